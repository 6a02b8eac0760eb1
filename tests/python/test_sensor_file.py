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
    # Without ``physics``, the preset's own (as Press-v1 takes it).
    assert env.unwrapped.physics == tacrom.attribute({"sensor": "gelsight-mini"}, "physics")
    # Both fingertips are Minis: the calibrated background of the real gel, not a colour.
    assert np.array_equal(obs["tactile_rgb"][0], obs["tactile_rgb"][1])
    assert obs["tactile_rgb"][0].std() > 1.0
    for _ in range(3):
        obs, *_ = env.step(np.array([0.0, -1.0, -1.0], np.float32))
    assert env.observation_space.contains(obs)


def test_the_gripper_scene_carries_minis_and_each_pad_fits_its_gel():
    import pathlib

    from tacrom.envs.gripper import PAD_SINK

    mini = [float(v) for v in tacrom.attribute({"sensor": "gelsight-mini"}, "size").split()]
    default = [float(v) for v in tacrom.attribute({}, "size").split()]
    scene = pathlib.Path(__file__).resolve().parents[2] / "examples" / "gripper.xml"
    spec = mujoco.MjSpec.from_file(str(scene))
    for s in spec.sensors:
        assert dict(s.plugin.config)["sensor"] == "gelsight-mini"

    def pads(model):
        return [(model.geom(p).size, model.geom(p).pos) for p in ("left_pad", "right_pad")]

    # The scene's pads, the default environment's and the Minis' environment's: each pad's
    # face the gel's face, PAD_SINK of its thickness below the gel's surface (x = 0).
    for model, (lx, ly, t) in (
        (spec.compile(), mini),
        (gym.make("tacrom/GripperLift-v1").unwrapped.model, default),
        (gym.make("tacrom/GripperLift-v1", sensor="gelsight-mini").unwrapped.model, mini),
    ):
        for side, (size, pos) in zip((-1.0, 1.0), pads(model)):
            np.testing.assert_allclose(size[1:], [lx / 2, ly / 2], rtol=1e-6)
            np.testing.assert_allclose(pos[0], side * (size[0] + PAD_SINK * t), rtol=1e-4)
    # The default environment's pads are the scene's as it was designed: 30 x 30 mm, 0.3 mm below.
    size, pos = pads(gym.make("tacrom/GripperLift-v1").unwrapped.model)[0]
    np.testing.assert_allclose([*size, pos[0]], [0.005, 0.015, 0.015, -0.0053], rtol=1e-9)
