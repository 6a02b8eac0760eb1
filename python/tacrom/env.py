"""A Gymnasium environment with a tactile observation: pressing and sliding a sphere on
the sensor of ``examples/press.xml``-like scenes (``tacrom/Press-v0``; ``tacrom/Press-v1``,
:mod:`tacrom.envs.press`, is its successor with proprioception, RGB images and rendering).

The observation is the sensor's depth image, ``float32`` of shape ``(H, W)`` in metres
(positive into the gel, within ``[0, T]``); the action moves the indenter's press target.
It is a small, complete example of wiring tacrom into RL code: any MJCF with a tacrom
sensor works the same way (``tacrom.depth(model, data, name)`` after ``mj_step``).
"""

from __future__ import annotations

from typing import Any, Optional

import gymnasium as gym
import mujoco
import numpy as np

import tacrom
from tacrom.envs.press import press_model


class PressEnv(gym.Env):
    """Press a sphere (radius 5 mm) into the gel and slide it along x.

    Action: ``[x, depth]`` targets in metres, ``x`` in [-5, 5] mm, ``depth`` in [0, 1] mm.
    Observation: depth image ``(H, W)`` float32, metres. Reward: minus the squared distance
    (mm^2) of the contact's centroid from ``target_x`` (a toy task: find a spot by touch).
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        physics: str = "rigid",
        resolution: tuple[int, int] = (64, 48),
        target_x: float = 0.002,
        steps_per_action: int = 25,
        max_steps: int = 50,
    ) -> None:
        width, height = resolution
        self.model, self.thickness = press_model(physics, resolution)
        self.data = mujoco.MjData(self.model)
        self.observation_space = gym.spaces.Box(
            0.0, self.thickness, shape=(height, width), dtype=np.float32
        )
        self.action_space = gym.spaces.Box(
            np.array([-0.005, 0.0], dtype=np.float32),
            np.array([0.005, 0.001], dtype=np.float32),
        )
        self.target_x = target_x
        self.steps_per_action = steps_per_action
        self.max_steps = max_steps
        self._steps = 0
        self._fov_x = 0.024

    def _observe(self) -> np.ndarray:
        return tacrom.depth(self.model, self.data, "touch").astype(np.float32)

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[0] = self.np_random.uniform(-0.004, 0.004)
        mujoco.mj_forward(self.model, self.data)
        self._steps = 0
        return self._observe(), {}

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = np.clip(np.asarray(action, dtype=np.float64), self.action_space.low, self.action_space.high)
        self.data.ctrl[:] = action
        for _ in range(self.steps_per_action):
            mujoco.mj_step(self.model, self.data)
        obs = self._observe()
        self._steps += 1
        total = float(obs.sum())
        if total > 0:
            cols = (np.arange(obs.shape[1]) + 0.5) / obs.shape[1] * self._fov_x - self._fov_x / 2
            centroid = float((obs.sum(axis=0) * cols).sum() / total)
            reward = -((centroid - self.target_x) * 1e3) ** 2
        else:
            centroid, reward = None, -25.0
        truncated = self._steps >= self.max_steps
        return obs, reward, False, truncated, {"centroid_x": centroid}
