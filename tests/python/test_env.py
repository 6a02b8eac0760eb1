"""The Gymnasium environment: spaces, observations within them, and a reward that tells
where the contact is."""

import gymnasium as gym
import numpy as np
import pytest

from tacrom.env import PressEnv


@pytest.mark.parametrize("physics", ["rigid", "coarse"])
def test_spaces_and_observations(physics):
    env = PressEnv(physics=physics, resolution=(32, 24), max_steps=3)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (24, 32) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    assert np.all(obs == 0.0)  # not pressed yet
    obs, reward, terminated, truncated, info = env.step(np.array([0.0, 0.0008], np.float32))
    assert env.observation_space.contains(obs) and obs.max() > 0.5e-3
    assert np.isfinite(reward) and not terminated and not truncated


def test_reward_finds_the_target_by_touch():
    env = PressEnv(physics="rigid", resolution=(64, 48), target_x=0.002)
    env.reset(seed=1)
    rewards = {}
    for x in (-0.002, 0.0, 0.002):
        _, reward, *_, info = env.step(np.array([x, 0.0008], np.float32))
        rewards[x] = reward
        assert info["centroid_x"] == pytest.approx(env.data.qpos[0], abs=2e-4)
    assert rewards[0.002] > rewards[0.0] > rewards[-0.002]


def test_checker_accepts_the_env():
    from gymnasium.utils.env_checker import check_env

    check_env(PressEnv(resolution=(16, 12)), skip_render_check=True)
