"""The registered Gymnasium environments: the checker, seeding, a grasp that lifts and
holds each object of the tactile gripper with touch where it should be, rendering, and
environments stepped in two processes."""

import functools
import json
import pathlib
import tempfile
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import tacrom  # noqa: F401  (registers the environments)
from tacrom.envs.base import make_renderer

IDS = ["tacrom/Press-v0", "tacrom/Press-v1", "tacrom/GripperLift-v1"]


def gl_error():
    """None when an OpenGL context can be made here, else the clear error that
    ``render_mode="rgb_array"`` raises."""
    env = gym.make("tacrom/Press-v1").unwrapped
    try:
        make_renderer(env.model, 24, 32).close()
    except RuntimeError as err:
        return err
    return None


GL_ERROR = gl_error()


@pytest.mark.parametrize("env_id", IDS)
def test_checker_accepts_the_registered_env(env_id):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # v0: "out of date, use v1"
        env = gym.make(env_id).unwrapped
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # Without OpenGL the render check cannot run; test_render_rgb_array says so.
        check_env(env, skip_render_check=GL_ERROR is not None)
    messages = [str(w.message) for w in caught if "gymnasium" in w.filename]
    assert messages == []


@pytest.mark.parametrize("env_id", ["tacrom/Press-v1", "tacrom/GripperLift-v1"])
def test_seeded_resets_give_identical_first_observations(env_id):
    a = gym.make(env_id, tactile_rgb=True)
    b = gym.make(env_id, tactile_rgb=True)
    obs_a, info_a = a.reset(seed=7)
    obs_b, info_b = b.reset(seed=7)
    assert obs_a.keys() == obs_b.keys() == a.observation_space.spaces.keys()
    for key in obs_a:
        assert np.array_equal(obs_a[key], obs_b[key]), key
    assert info_a == info_b
    for _ in range(3):
        action = a.action_space.sample()
        steps = a.step(action), b.step(action)
        for key in obs_a:
            assert np.array_equal(steps[0][0][key], steps[1][0][key]), key


def test_both_environments_default_to_the_sensors_default_physics():
    """Press-v1 and GripperLift-v1 run the sensor's default physics (rom, on the linear
    gel); a sensor file given without ``physics`` keeps its own."""
    press = gym.make("tacrom/Press-v1").unwrapped
    assert press.physics == "rom" == tacrom.attribute_default("physics")
    assert tacrom.layout(press.model, "touch")["solver"]["name"] == "linear"
    grip = gym.make("tacrom/GripperLift-v1").unwrapped
    assert grip.physics == "rom"
    for sensor in ("left_touch", "right_touch"):
        assert tacrom.layout(grip.model, sensor)["solver"]["name"] == "linear"
    mini = gym.make("tacrom/GripperLift-v1", sensor="gelsight-mini").unwrapped
    assert mini.physics == tacrom.attribute({"sensor": "gelsight-mini"}, "physics")


def _attributes(model, instance: int) -> dict:
    """The tacrom plugin instance's attributes as MuJoCo compiled them (``plugin_attr``:
    each value null-terminated, in the plugin's declared order; empty where unset)."""
    names = [a["name"] for a in tacrom.attribute_table()]
    start = int(model.plugin_attradr[instance])
    values = bytes(model.plugin_attr[start:]).split(b"\0")[: len(names)]
    return {n: v.decode() for n, v in zip(names, values)}


def test_the_grasp_holds_a_frame_within_5_um_unless_told():
    """GripperLift-v1 sets its sensors' ``hold`` to ``GRASP_HOLD`` (5 um) where
    ``sensor_config`` gives none, and keeps the one given (the sensor's own default then
    applies to other environments)."""
    from tacrom.envs import gripper

    assert gripper.GRASP_HOLD == 5e-6
    default = gym.make("tacrom/GripperLift-v1").unwrapped.model
    told = gym.make("tacrom/GripperLift-v1", sensor_config={"hold": "1e-6"}).unwrapped.model
    for instance in range(2):
        assert float(_attributes(default, instance)["hold"]) == 5e-6
        assert float(_attributes(told, instance)["hold"]) == 1e-6
    press = gym.make("tacrom/Press-v1").unwrapped.model
    assert _attributes(press, 0)["hold"] == ""
    # A sensor file's own hold stands: the environment leaves the attribute to it.
    with tempfile.TemporaryDirectory() as folder:
        path = pathlib.Path(folder) / "sensor.json"
        path.write_text(
            json.dumps({"format": "tacrom-sensor-1", "attributes": {"hold": "2e-06"}})
        )
        filed = gym.make("tacrom/GripperLift-v1", sensor=str(path)).unwrapped.model
        for instance in range(2):
            assert _attributes(filed, instance)["hold"] == ""
            assert _attributes(filed, instance)["sensor"] == str(path)


def test_a_step_is_frame_skip_physics_steps_then_one_evaluation():
    """An environment step is ``frame_skip`` physics steps with the sensors off (MuJoCo
    repeating the step itself) and one ``mj_forward`` that evaluates them: the same state
    and sensor data, bit for bit, as those steps taken one call at a time on a copy."""
    import mujoco

    env = gym.make("tacrom/Press-v1").unwrapped
    env.reset(seed=3)
    m = env.model
    for action in ([0.3, 0.8], [-0.5, 1.0], [0.9, 0.2]):
        copy = mujoco.MjData(m)
        mujoco.mj_copyData(copy, m, env.data)
        env.step(np.array(action, np.float32))
        copy.ctrl[:] = env.data.ctrl
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        for _ in range(env.frame_skip):
            mujoco.mj_step(m, copy)
        m.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        mujoco.mj_forward(m, copy)
        assert env.data.time == copy.time
        assert np.array_equal(env.data.qpos, copy.qpos)
        assert np.array_equal(env.data.qvel, copy.qvel)
        assert np.array_equal(env.data.sensordata, copy.sensordata)
        assert env.data.sensordata.max() > 0.0


def test_seeds_choose_the_episode():
    env = gym.make("tacrom/GripperLift-v1")
    objects = {env.reset(seed=s)[1]["object"] for s in range(12)}
    assert objects == {"box", "cylinder", "hexagon"}
    press = gym.make("tacrom/Press-v1")
    xs = {float(press.reset(seed=s)[0]["joint_pos"][0]) for s in range(3)}
    assert len(xs) == 3


def test_observation_keys_and_shapes():
    env = gym.make("tacrom/GripperLift-v1", resolution=(40, 30), tactile_rgb=True)
    obs, _ = env.reset(seed=0)
    assert obs["joint_pos"].shape == (4,) and obs["joint_vel"].shape == (4,)
    assert obs["gripper_opening"] == pytest.approx(0.07, abs=1e-6)
    assert obs["tactile_depth"].shape == (2, 30, 40) and obs["tactile_depth"].dtype == np.float32
    assert obs["tactile_rgb"].shape == (2, 30, 40, 3) and obs["tactile_rgb"].dtype == np.uint8
    # The flat gel: zero depth, the uniform background colour.
    assert not obs["tactile_depth"].any()
    assert np.array_equal(obs["tactile_rgb"][0, 0, 0], [120, 125, 135])
    assert (obs["tactile_rgb"] == obs["tactile_rgb"][0, 0, 0]).all()
    assert "tactile_rgb" not in gym.make("tacrom/GripperLift-v1").reset(seed=0)[0]
    with pytest.raises(ValueError, match="physics"):
        gym.make("tacrom/Press-v1", physics="fine")


@pytest.mark.parametrize("obj", ["box", "cylinder", "hexagon"])
def test_gripper_lifts_and_holds_the_object(obj):
    env = gym.make("tacrom/GripperLift-v1", object=obj, tactile_rgb=True)
    obs, info = env.reset(seed=1)
    assert info["object"] == obj and info["contacts"] == 0

    def run(action, steps):
        nonlocal obs, info
        for _ in range(steps):
            obs, reward, terminated, truncated, info = env.step(np.array(action, np.float32))
            assert not terminated and not truncated
        return obs, info

    run([0, -1, -1], 15)  # down to the working height, open: around the object
    assert not obs["tactile_depth"].any(), "touch before contact"
    assert info["object_height"] == pytest.approx(0, abs=5e-4)
    for _ in range(10):  # close; the first contact must not slam through the 4 mm gel
        run([0, -1, 1], 1)
        assert obs["tactile_depth"].max() < 2e-3, obs["tactile_depth"].max()
    depth = obs["tactile_depth"].reshape(2, -1).max(axis=1)
    assert (depth > 3e-4).all() and (depth < 2e-3).all(), depth
    assert (obs["tactile_rgb"] != obs["tactile_rgb"][:, :1, :1]).any(axis=(1, 2, 3)).all()
    run([0, 0.5, 1], 15)  # lift: 60 mm up
    heights, slips = [], []
    lift = env.unwrapped.model.joint("lift").qposadr[0]
    for _ in range(25):  # hold for 1 s (40 ms steps)
        run([0, 0.5, 1], 1)
        heights.append(info["object_height"])
        # How far the object has moved down the pads (the gripper still rises the last
        # tenths of a millimetre of its filtered lift).
        slips.append(info["object_height"] - env.unwrapped.data.qpos[lift])
        assert info["contacts"] == 2 and info["is_success"]
        assert (obs["tactile_depth"].reshape(2, -1).max(axis=1) > 3e-4).all()
    assert min(heights) > 0.05, heights
    assert max(heights) - min(heights) < 1e-3, heights
    # Held, not creeping down the pads: MuJoCo's soft friction let it slip 4 to 6 um a
    # step (0.1 to 0.15 mm/s) before the scene's no-slip pass, each step a new press.
    assert max(slips) - min(slips) < 1e-5, np.diff(slips)
    run([0, -1, 1], 20)  # put it down
    run([0, -1, -1], 10)  # and let go
    assert info["object_height"] == pytest.approx(0, abs=1e-3)
    assert not obs["tactile_depth"].any()


def lift_trace(servo_time):
    """The lift joint's height and velocity at every physics step of GripperLift-v1 (rigid,
    one physics step an environment step): 25 steps holding the reset's target (the lift
    action that is ``START_LIFT``), then 300 lifting from the table's height to 60 mm (the
    grasp cycle's lift) after the gripper was brought down there."""
    from tacrom.envs import gripper

    env = gripper.GripperLiftEnv(physics="rigid", object="box", servo_time=servo_time, frame_skip=1)
    env.reset(seed=0)
    m, d = env.model, env.data
    q, dof = m.joint("lift").qposadr[0], m.joint("lift").dofadr[0]
    hold = 2.0 * gripper.START_LIFT / gripper.LIFT_RANGE - 1.0
    held = []
    for _ in range(25):
        env.step(np.array([0.0, hold, -1.0], np.float32))
        held.append(d.qpos[q])
    for _ in range(1000):  # down to the table's height
        env.step(np.array([0.0, -1.0, -1.0], np.float32))
    lifted = []
    for _ in range(300):
        env.step(np.array([0.0, 0.5, -1.0], np.float32))
        lifted.append((d.qpos[q], d.qvel[dof]))
    return np.array(held), np.array(lifted), m.opt.timestep


def test_the_arms_servos_follow_a_filtered_target():
    """GripperLift-v1's carry and lift servos follow their targets through a 0.1 s filter
    (``servo_time``): held at the reset's target, the gripper stays where the reset put it
    (the filter starts there); lifted from the table to 60 mm, it accelerates at under 1.5 g
    (the unfiltered servo: over 5 g, a jolt the grasp's friction has to pass on to the
    object) and is within 0.5 mm of the height after 0.6 s (15 environment steps), as the
    grasp tests ask."""
    from tacrom.envs import gripper

    for servo_time in (gripper.SERVO_TIME, 0.0):
        held, lifted, h = lift_trace(servo_time)
        assert np.abs(held - gripper.START_LIFT).max() < 1e-6, (servo_time, held)
        peak = np.abs(np.diff(lifted[:, 1])).max() / h / 9.81
        if servo_time > 0:
            assert peak < 1.5, peak
        else:
            assert peak > 5.0, peak
        assert abs(lifted[299, 0] - 0.06) < 5e-4, lifted[299, 0]
    with pytest.raises(ValueError, match="servo_time"):
        gripper.GripperLiftEnv(servo_time=-0.1)


def test_physics_modes_agree_on_where_the_press_is():
    rigid = gym.make("tacrom/Press-v1", physics="rigid", resolution=(32, 24))
    coarse = gym.make("tacrom/Press-v1", physics="coarse", resolution=(32, 24))
    images = []
    for env in (rigid, coarse):
        env.reset(seed=0)
        obs, *_ = env.step(np.array([0.2, 0.6], np.float32))
        images.append(obs["tactile_depth"][0])
    for img in images:
        assert img.max() > 5e-4
    peaks = [np.unravel_index(np.argmax(img), img.shape) for img in images]
    assert abs(int(peaks[0][1]) - int(peaks[1][1])) <= 1
    assert not np.array_equal(images[0], images[1])


@pytest.mark.parametrize("env_id", ["tacrom/Press-v1", "tacrom/GripperLift-v1"])
def test_render_rgb_array(env_id):
    env = gym.make(env_id, render_mode="rgb_array", render_size=(160, 120))
    env.reset(seed=0)
    if GL_ERROR is not None:
        with pytest.raises(RuntimeError, match="OpenGL"):
            env.render()
        pytest.skip(f"no OpenGL context on this machine: {GL_ERROR}")
    frame = env.render()
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
    assert frame.std() > 5  # a scene, not a blank frame
    env.close()
    env.close()


def test_async_vector_env_steps_press_in_two_processes():
    envs = gym.vector.AsyncVectorEnv(
        [lambda: gym.make("tacrom/Press-v1", resolution=(32, 24))] * 2
    )
    try:
        obs, _ = envs.reset(seed=[0, 1])
        assert obs["tactile_depth"].shape == (2, 1, 24, 32)
        assert obs["joint_pos"][0, 0] != obs["joint_pos"][1, 0]
        for _ in range(3):
            obs, reward, terminated, truncated, info = envs.step(
                np.array([[0.0, 1.0], [0.4, 1.0]], np.float32)
            )
        assert reward.shape == (2,) and np.isfinite(reward).all()
        assert (obs["tactile_depth"].reshape(2, -1).max(axis=1) > 5e-4).all()
        # The two presses sit 2 mm apart: their contact centroids say so.
        assert info["centroid_x"][1] - info["centroid_x"][0] == pytest.approx(0.002, abs=3e-4)
    finally:
        envs.close()


def test_async_vector_env_with_a_gel_in_forkserver_processes():
    # Workers from a forkserver (the way to go with threads > 1, whose worker pool a forked
    # child would not have; test_fork.py covers fork with one thread). "tacrom.envs:"
    # makes them import and register tacrom.
    here = gym.make("tacrom/Press-v1", physics="coarse", resolution=(16, 12))
    here.reset(seed=0)
    here.step(np.array([0.0, 1.0], np.float32))
    make = functools.partial(
        gym.make, "tacrom.envs:tacrom/Press-v1", physics="coarse", resolution=(16, 12)
    )
    envs = gym.vector.AsyncVectorEnv([make] * 2, context="forkserver")
    try:
        envs.reset(seed=[0, 1])
        obs, *_ = envs.step(np.array([[0.0, 1.0], [0.4, 1.0]], np.float32))
        assert (obs["tactile_depth"].reshape(2, -1).max(axis=1) > 5e-4).all()
    finally:
        envs.close()
