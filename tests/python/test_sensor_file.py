"""Sensor files and the shipped GelSight Mini (``sensor="gelsight-mini"``): loaded in MJCF
with attributes beside it overriding it, refused with the fault named, and selectable in
both environments."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import tacrom
from conftest import evaluate, with_config


def test_the_shipped_preset_reads_as_attributes():
    a = tacrom.sensor_file("gelsight-mini")
    lx, ly, t = (float(v) for v in a["size"].split())
    fx, fy = (float(v) for v in a["fov"].split())
    # The Mini's image: 640 x 480 pixels of 0.0295 mm, inside the gel.
    assert a["resolution"] == "640 480"
    assert abs(fx - 640 * 0.0295e-3) < 1e-9 and abs(fy - 480 * 0.0295e-3) < 1e-9
    assert fx < lx and fy < ly and 0 < t < 0.01
    assert a["view"] == "camera"
    assert a["optics"].endswith("optics.json")
    assert tacrom.attribute({"sensor": "gelsight-mini"}, "poisson") == a["poisson"]
    assert tacrom.attribute({"sensor": "gelsight-mini", "poisson": "0.3"}, "poisson") == "0.3"


def test_the_preset_loads_in_mjcf_and_the_mjcf_overrides_it(press_xml):
    xml = with_config(press_xml, sensor="gelsight-mini", outputs="depth rgb", resolution="64 48")
    model = mujoco.MjModel.from_xml_string(xml)
    layout = tacrom.layout(model, "touch")
    assert (layout["width"], layout["height"]) == (64, 48)
    data = mujoco.MjData(model)
    flat = evaluate(model, data, 0.0)
    pressed = evaluate(model, data, 0.3e-3)
    for out in (flat, pressed):
        assert np.all(np.isfinite(out["depth"])) and np.all(np.isfinite(out["rgb"]))
    assert pressed["depth"].max() > 1e-4
    # The flat gel shows the calibrated background: the real gel's, not a uniform colour.
    assert flat["rgb"].std() > 1.0
    assert np.abs(pressed["rgb"] - flat["rgb"]).max() > 10


def test_a_bad_sensor_value_names_the_sensor_and_the_attribute(press_xml):
    with pytest.raises(ValueError) as err:
        mujoco.MjModel.from_xml_string(with_config(press_xml, sensor="no-such-sensor"))
    message = str(err.value)
    assert "'touch'" in message and "'sensor'" in message and "no-such-sensor" in message
    with pytest.raises(ValueError, match="no-such-sensor"):
        tacrom.sensor_file("no-such-sensor")


def test_press_env_takes_the_preset_with_its_physics():
    env = gym.make("tacrom/Press-v1", sensor="gelsight-mini", resolution=(32, 24))
    obs, _ = env.reset(seed=0)
    assert env.unwrapped.physics == tacrom.sensor_file("gelsight-mini")["physics"]
    assert env.unwrapped._fov_x == pytest.approx(640 * 0.0295e-3)
    for _ in range(3):
        obs, reward, *_ = env.step(np.array([0.0, 0.0], np.float32))
    depth = obs["tactile_depth"]
    assert depth.shape == (1, 24, 32) and depth.max() > 0 and np.isfinite(reward)
    assert env.observation_space.contains(obs)


def test_gripper_env_takes_the_preset():
    env = gym.make("tacrom/GripperLift-v1", sensor="gelsight-mini", tactile_rgb=True, object="box")
    obs, _ = env.reset(seed=0)
    assert env.unwrapped.physics == "rigid"
    # Both fingertips are Minis: the calibrated background of the real gel, not a colour.
    assert np.array_equal(obs["tactile_rgb"][0], obs["tactile_rgb"][1])
    assert obs["tactile_rgb"][0].std() > 1.0
    for _ in range(3):
        obs, *_ = env.step(np.array([0.0, -1.0, -1.0], np.float32))
    assert env.observation_space.contains(obs)
