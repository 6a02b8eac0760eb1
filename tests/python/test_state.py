"""Sensor state per MjData through the real `mujoco` Python package: mj_resetData restores
the undeformed gel after a frictional slide, mj_copyData carries a gel with history,
mj_getState / mj_setState (mjSTATE_PLUGIN) carry it exactly, mujoco.rollout in threads
equals stepping alone, and an off-centre press lands where the documented image layout
says.

Each scene is cheap: a coarse gel, 32 x 24 images, presses of at most 1 mm."""

import mujoco
import mujoco.rollout
import numpy as np
import pytest

import tacrom

W, H = 32, 24
FOV = (0.024, 0.018)
R = 0.005

# A fixed sensor (site "gel", top face at z = 0) and a sphere on three slide joints:
# qpos = [x, y, press], the sphere touching the gel at qpos = 0.
SCENE = """
<mujoco>
  <extension><plugin plugin="tacrom.tactile"/></extension>
  <option gravity="0 0 0"/>
  <worldbody>
    <body name="sensor">
      <geom name="pad" type="box" size="0.015 0.015 0.002" pos="0 0 -0.006"/>
      <site name="gel"/>
    </body>
    <body name="indenter" pos="0 0 {lift}">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <joint name="press" type="slide" axis="0 0 -1"/>
      {geom}
    </body>
  </worldbody>
  <keyframe><key name="start" qpos="0 0 0"/></keyframe>
  <sensor>
    <plugin name="touch" plugin="tacrom.tactile" objtype="site" objname="gel">
      <config key="physics" value="{physics}"/>
      <config key="outputs" value="{outputs}"/>
      <config key="resolution" value="{W} {H}"/>
      <config key="friction" value="1.0"/>{extra}
    </plugin>
  </sensor>
</mujoco>
"""
SPHERE = f'<geom type="sphere" size="{R}" contype="0" conaffinity="0"/>'

# A deep frictional press slid 1.5 mm sideways (a gel with history), then a shallow press
# under the slid sphere.
HISTORY = [(0, 0, 0.5e-3), (0, 0, 1.0e-3), (0.5e-3, 0, 1.0e-3), (1.0e-3, 0, 1.0e-3),
           (1.5e-3, 0, 1.0e-3), (1.5e-3, 0.2e-3, 0.9e-3)]
SHALLOW = (1.5e-3, 0.2e-3, 0.2e-3)


def model(physics="coarse", outputs="depth force", geom=SPHERE, lift=R, **config):
    extra = "".join(f'\n      <config key="{k}" value="{v}"/>' for k, v in config.items())
    xml = SCENE.format(lift=lift, geom=geom, physics=physics, outputs=outputs, W=W, H=H,
                       extra=extra)
    return mujoco.MjModel.from_xml_string(xml)


def evaluate(m, d, pose):
    """All outputs of the sensor with the indenter at ``pose`` = (x, y, press)."""
    d.qpos[:3] = pose
    mujoco.mj_forward(m, d)
    out = tacrom.outputs(m, d, "touch")
    return {k: np.array(v, copy=True) for k, v in out.items()}


def assert_same(a, b, what):
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=f"{what}: {k}")


def history_shows(a, b, press):
    """Whether two outputs differ by more than 10 % of the press depth or of the force."""
    fz = b["force"][2]
    return (np.abs(a["depth"] - b["depth"]).max() > 0.1 * press
            or np.abs(a["force"] - b["force"]).max() > 0.1 * fz)


def test_reset_after_frictional_slide_equals_fresh_gel():
    """Catches: mj_resetData leaving gel state behind (a no-op or partial reset). After a
    deep frictional slide and a reset, one shallow press must equal a fresh MjData's, bit
    for bit: the same deterministic computation on the same input; and without the reset
    the same press differs (the history is real, so the test has teeth)."""
    m = model()
    d = mujoco.MjData(m)
    for pose in HISTORY:
        evaluate(m, d, pose)
    kept = mujoco.MjData(m)
    mujoco.mj_copyData(kept, m, d)
    with_history = evaluate(m, kept, SHALLOW)

    mujoco.mj_resetData(m, d)
    after_reset = evaluate(m, d, SHALLOW)
    fresh = evaluate(m, mujoco.MjData(m), SHALLOW)
    assert fresh["force"][2] > 0.0
    assert_same(after_reset, fresh, "reset gel vs fresh gel")
    assert history_shows(with_history, fresh, SHALLOW[2])


def test_copy_continues_identically_and_keeps_history():
    """Catches: mj_copyData not carrying the gel (a fresh sensor in the copy, a shared or
    partial state). Original and copy continue one frictional trajectory and agree bit for
    bit every frame (the same deterministic computation from the same state); the copy's
    last frame differs from a fresh gel pressed straight to the final pose."""
    m = model()
    original = mujoco.MjData(m)
    for pose in HISTORY[:4]:
        evaluate(m, original, pose)
    copy = mujoco.MjData(m)
    mujoco.mj_copyData(copy, m, original)
    rest = HISTORY[4:] + [SHALLOW]
    for i, pose in enumerate(rest):
        a = evaluate(m, original, pose)
        b = evaluate(m, copy, pose)
        assert a["depth"].max() > 0.0
        assert_same(a, b, f"frame {i} after the copy")
    fresh = evaluate(m, mujoco.MjData(m), SHALLOW)
    assert history_shows(b, fresh, SHALLOW[2])


def test_a_copy_of_a_thin_gels_rom_sensor_continues_identically():
    """Catches: mj_copyData giving the copy's reduced-order model its own gel's lattice
    instead of the served one (rom on a 12 x 12 x 1 mm gel reads the gel in thicknesses
    through a window of its lattice). A frictional press and slide on the thin gel, then a
    copy: original and copy agree bit for bit every frame after it."""
    m = model(physics="rom", size="0.012 0.012 0.001", fov="0.012 0.012", lift=R)
    original = mujoco.MjData(m)
    poses = [(0, 0, 0.2e-3), (0.3e-3, 0, 0.3e-3), (0.6e-3, 0.1e-3, 0.3e-3),
             (0.9e-3, 0.1e-3, 0.25e-3), (0.9e-3, 0.3e-3, 0.1e-3)]
    for pose in poses[:2]:
        evaluate(m, original, pose)
    copy = mujoco.MjData(m)
    mujoco.mj_copyData(copy, m, original)
    for i, pose in enumerate(poses[2:]):
        a = evaluate(m, original, pose)
        b = evaluate(m, copy, pose)
        assert abs(a["depth"].max() - pose[2]) < 0.1 * pose[2]
        assert_same(a, b, f"frame {i} after the copy")


def test_off_centre_box_lands_at_documented_pixels():
    """Catches: a mirrored or transposed image. A box 6 x 2 mm (long along x) pressed at
    (+5, +3) mm must appear where the documented layout puts it (row 0 the +y edge,
    column 0 the -x edge): its depth-weighted centroid within one pixel (0.75 mm) of the
    box centre (the footprint is symmetric about it; a flipped axis moves it 10 or 6 mm),
    and the footprint wider than tall."""
    box = ('<geom type="box" size="0.003 0.001 0.001" pos="0.005 0.003 0.001" '
           'contype="0" conaffinity="0"/>')
    for physics in ("rigid", "coarse"):
        m = model(physics=physics, outputs="depth", geom=box, lift=0.0)
        depth = evaluate(m, mujoco.MjData(m), (0, 0, 0.3e-3))["depth"]
        assert depth.shape == (H, W) and depth.max() > 0.2e-3
        x = -FOV[0] / 2 + (np.arange(W) + 0.5) * FOV[0] / W
        y = FOV[1] / 2 - (np.arange(H) + 0.5) * FOV[1] / H
        total = depth.sum()
        cx = (depth.sum(axis=0) * x).sum() / total
        cy = (depth.sum(axis=1) * y).sum() / total
        pixel = FOV[0] / W
        assert abs(cx - 0.005) < pixel and abs(cy - 0.003) < pixel, (physics, cx, cy)
        vx = (depth.sum(axis=0) * (x - cx) ** 2).sum() / total
        vy = (depth.sum(axis=1) * (y - cy) ** 2).sum() / total
        assert vx > 2 * vy, (physics, vx, vy)


STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS | mujoco.mjtState.mjSTATE_PLUGIN

# Every physics mode with each solver whose state MuJoCo's state holds: the relaxation (the
# coarse gel's own, with the linear solver for the contacts it misses), the linear solver,
# the total relaxation and Newton's method, the first two under rom too (rom's default is the linear gel;
# the relaxation's rom is model="rom-default").
KEPT = [("rigid", {}), ("coarse", {}), ("coarse", {"solver": "linear"}),
        ("coarse", {"solver": "total"}), ("coarse", {"solver": "newton", "dx": "0.002"}),
        ("rom", {}),
        ("rom", {"model": "rom-default"})]


def get_state(m, d):
    s = np.empty(mujoco.mj_stateSize(m, STATE))
    mujoco.mj_getState(m, d, s, STATE)
    return s


@pytest.mark.parametrize("physics,config", KEPT, ids=lambda v: str(v))
def test_a_restored_state_replays_the_original_bit_for_bit(physics, config):
    """Catches: gel state outside MuJoCo's state (a restored MjData that forgets the
    friction anchors, the deformed gel or the warm starts). Three frames of a frictional
    press and slide; the state taken; four more frames (a slide, a lift to a shallow
    press); a new MjData given the state with mj_setState, and the first MjData rewound to
    it, replay them: equal to the last bit (the same deterministic computation from the
    same state). A fresh gel pressed the same way differs, so the history is real."""
    outputs = "depth" if physics == "rigid" else "depth force shear"
    m = model(physics=physics, outputs=outputs, **config)
    assert (m.npluginstate == 0) == (physics == "rigid"), m.npluginstate
    d = mujoco.MjData(m)
    for pose in HISTORY[:3]:
        evaluate(m, d, pose)
    saved = get_state(m, d)
    rest = HISTORY[3:] + [SHALLOW]
    original = [evaluate(m, d, pose) for pose in rest]
    restored = mujoco.MjData(m)
    mujoco.mj_setState(m, restored, saved, STATE)
    for i, pose in enumerate(rest):
        assert_same(original[i], evaluate(m, restored, pose), f"restored, frame {i}")
    mujoco.mj_setState(m, d, saved, STATE)
    for i, pose in enumerate(rest):
        assert_same(original[i], evaluate(m, d, pose), f"rewound, frame {i}")
    if physics != "rigid":
        fresh = evaluate(m, mujoco.MjData(m), rest[0])
        assert history_shows(original[0], fresh, rest[0][2])
        # mj_resetData, mj_resetDataKeyframe and a state of the fresh gel each give the
        # fresh gel back.
        mujoco.mj_resetData(m, d)
        assert_same(fresh, evaluate(m, d, rest[0]), "after mj_resetData")
        mujoco.mj_setState(m, d, saved, STATE)
        mujoco.mj_resetDataKeyframe(m, d, 0)
        assert_same(fresh, evaluate(m, d, rest[0]), "after mj_resetDataKeyframe")
        mujoco.mj_setState(m, d, get_state(m, mujoco.MjData(m)), STATE)
        assert_same(fresh, evaluate(m, d, rest[0]), "a fresh gel's state")


# After the history: the sphere held (the same pose, then moved 40 nm: both under the default
# `hold` of 0.1 um, so the last solve's frame again), then moved on by 2 um (a solve).
HELD = [HISTORY[3], (1.0e-3 + 4e-8, 0, 1.0e-3), (1.0e-3 + 2e-6, 0, 1.0e-3),
        (1.0e-3 + 2e-6, 0, 1.0e-3), HISTORY[4]]


@pytest.mark.parametrize("physics,config", KEPT, ids=lambda v: str(v))
def test_held_frames_repeat_the_last_solve_and_replay_bit_for_bit(physics, config):
    """Catches: a held frame (indenters moved less than `hold` since the last solve) that
    solves anyway or gives anything but the last solve's outputs, and held frames whose
    outputs depend on what MuJoCo's state does not carry (the images of the last solve).
    The state is taken right after a solve; the original's next frames are held (the
    same pose, then 40 nm away) and reuse its images, while the restored MjData has none
    and computes them again from the state: equal to the last bit. With `hold="0"` the
    40 nm frame is solved, and differs."""
    outputs = "depth" if physics == "rigid" else "depth force shear"
    m = model(physics=physics, outputs=outputs, **config)
    d = mujoco.MjData(m)
    for pose in HISTORY[:3]:
        evaluate(m, d, pose)
    saved = get_state(m, d)
    original = [evaluate(m, d, pose) for pose in HELD]
    # The held frames are the first one's outputs; the one moved 2 um is not. Rigid has no
    # state, and no frame of it is held.
    if physics == "rigid":
        assert not np.array_equal(original[0]["depth"], original[1]["depth"])
    else:
        assert_same(original[0], original[1], "held 40 nm away")
        assert_same(original[2], original[3], "held at the same pose")
    assert not np.array_equal(original[0]["depth"], original[2]["depth"])
    restored = mujoco.MjData(m)
    mujoco.mj_setState(m, restored, saved, STATE)
    for i, pose in enumerate(HELD):
        assert_same(original[i], evaluate(m, restored, pose), f"restored, frame {i}")
    # Restored between a solve and its held frame: the held frame computed again.
    mujoco.mj_setState(m, restored, saved, STATE)
    evaluate(m, restored, HELD[0])
    between = get_state(m, restored)
    again = mujoco.MjData(m)
    mujoco.mj_setState(m, again, between, STATE)
    assert_same(original[1], evaluate(m, again, HELD[1]), "held frame after a restore")
    if physics != "rigid":
        m0 = model(physics=physics, outputs=outputs, hold="0", **config)
        d0 = mujoco.MjData(m0)
        for pose in HISTORY[:3] + HELD[:2]:
            solved = evaluate(m0, d0, pose)
        assert not np.array_equal(solved["depth"], original[1]["depth"])


# A 24 mm box face (400 node columns under it) pressed 0.4 mm and then shaken by microns, as
# a grasp held in MuJoCo: the linear solver's frictional solves of these frames are split
# before Newton's method finishes them (see `a_shaken_grasp_splits_to_newtons_answer`).
FACE = '<geom type="box" size="0.012 0.012 0.005" contype="0" conaffinity="0"/>'
SHAKEN = [(0, 0, 0.2e-3), (0, 0, 0.4e-3), (3e-6, 1e-6, 0.401e-3), (-2e-6, 2e-6, 0.399e-3),
          (1e-6, -3e-6, 0.4e-3), (2e-6, 1e-6, 0.4005e-3), (0, 0, 0.3e-3)]


def test_a_restored_state_replays_a_shaken_grasp_on_the_linear_gel_bit_for_bit():
    """Catches: a path through the linear solver's frictional solve that depends on what
    MuJoCo's state does not carry (its kept factors, for one). The state taken after three
    frames of the shaken face; a new MjData given it replays the next four frames equal to
    the last bit."""
    m = model(physics="coarse", outputs="depth force", geom=FACE, lift=0.005,
              solver="linear")
    d = mujoco.MjData(m)
    for pose in SHAKEN[:3]:
        evaluate(m, d, pose)
    saved = get_state(m, d)
    original = [evaluate(m, d, pose) for pose in SHAKEN[3:]]
    assert original[0]["force"][2] > 0
    restored = mujoco.MjData(m)
    mujoco.mj_setState(m, restored, saved, STATE)
    for i, pose in enumerate(SHAKEN[3:]):
        assert_same(original[i], evaluate(m, restored, pose), f"restored, frame {i}")


def test_a_state_that_does_not_fit_the_sensor_restarts_the_gel_with_a_warning(capfd):
    """Catches: a crash or a NaN from a state that is not this sensor's (numbers written by
    hand, another model's). Its plugin part overwritten with a list length beyond its
    bound, then with NaN: the sensor warns, names the fault, and carries on from the
    undeformed gel, equal to a fresh one."""
    m = model()
    d = mujoco.MjData(m)
    for pose in HISTORY[:3]:
        evaluate(m, d, pose)
    saved = get_state(m, d)
    fresh = evaluate(m, mujoco.MjData(m), HISTORY[3])
    plugin = saved.size - m.npluginstate
    for fill in (1e9, np.nan):
        bad = saved.copy()
        bad[plugin + 3:] = fill
        other = mujoco.MjData(m)
        mujoco.mj_setState(m, other, bad, STATE)
        out = evaluate(m, other, HISTORY[3])
        assert all(np.isfinite(v).all() for v in out.values())
        assert_same(fresh, out, f"a state filled with {fill}")
        err = capfd.readouterr().err
        assert "'touch'" in err and "cannot be restored" in err, err


def test_a_state_that_is_not_whole_says_so_and_restarts(capfd):
    """A state whose header says it does not hold the whole gel (written where it did not
    fit in plugin_state): a restored state warns and the gel restarts undeformed, equal to
    a fresh gel, rather than continuing from a gel it does not have. The header's flag is
    cleared by hand here, as such a write leaves it."""
    m = model()
    d = mujoco.MjData(m)
    for pose in HISTORY[:2]:
        evaluate(m, d, pose)
    saved = get_state(m, d)
    saved[saved.size - m.npluginstate + 2] = 0.0
    restored = mujoco.MjData(m)
    mujoco.mj_setState(m, restored, saved, STATE)
    assert_same(evaluate(m, mujoco.MjData(m), HISTORY[2]), evaluate(m, restored, HISTORY[2]),
                "restored vs fresh")
    err = capfd.readouterr().err
    assert "'touch'" in err and "restarts undeformed" in err, err


def test_rollout_in_threads_equals_stepping_each_state_alone():
    """Catches: plugin state that mujoco.rollout does not carry, or instances that share
    state across threads. A sphere sliding at constant speed across the gel (no gravity,
    no damping) from four initial states of one trajectory (one of them fresh, three with
    a frictional history), rolled out five steps on two MjData in two threads: the
    sensordata equal, to the last bit, those of stepping each state alone in a new
    MjData."""
    m = model(outputs="depth force")
    m.opt.timestep = 0.005
    d = mujoco.MjData(m)
    d.qpos[:3] = (0, 0, 0.6e-3)
    d.qvel[:3] = (0.1, 0.05, 0.02)
    starts = []
    for step in range(9):
        if step % 3 == 0:
            starts.append(get_state(m, d))
        mujoco.mj_step(m, d)
    starts.append(get_state(m, d))
    starts = np.array(starts)
    nstep = 5
    # The rollout's states are mjSTATE_FULLPHYSICS, which holds mjSTATE_PLUGIN.
    assert STATE == mujoco.mjtState.mjSTATE_FULLPHYSICS
    _, sensordata = mujoco.rollout.rollout(
        m, [mujoco.MjData(m), mujoco.MjData(m)], starts, nstep=nstep)
    assert np.abs(sensordata).max() > 0
    for b, start in enumerate(starts):
        alone = mujoco.MjData(m)
        mujoco.mj_setState(m, alone, start, STATE)
        for t in range(nstep):
            mujoco.mj_step(m, alone)
            np.testing.assert_array_equal(sensordata[b, t], alone.sensordata,
                                          err_msg=f"rollout {b}, step {t}")


def test_a_coupled_gel_replays_its_pushes_bit_for_bit():
    """Catches: coupling memory outside MuJoCo's state (the damping's last wrenches, the
    passivity account, the poses the passive stage compares with). The 20 g ball of
    examples/rest.xml thrown at the coupled gel at 0.1 m/s: the state taken after 5
    steps (the ball pressing into the gel), 15 more steps; a new MjData given the state
    replays the ball's trajectory and the sensordata to the last bit."""
    from conftest import ROOT

    m = mujoco.MjModel.from_xml_string((ROOT / "examples" / "rest.xml").read_text())
    d = mujoco.MjData(m)
    d.qvel[2] = -0.1
    for _ in range(5):
        mujoco.mj_step(m, d)
    saved = get_state(m, d)

    def run(data):
        out = []
        for _ in range(15):
            mujoco.mj_step(m, data)
            out.append(np.concatenate([data.qpos, data.qvel, data.sensordata]))
        return np.array(out)

    original = run(d)
    restored = mujoco.MjData(m)
    mujoco.mj_setState(m, restored, saved, STATE)
    np.testing.assert_array_equal(original, run(restored))
    assert np.abs(original[:, 2] - original[0, 2]).max() > 1e-5, "the ball did not move"
