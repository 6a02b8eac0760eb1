"""The gel that pushes back through MuJoCo's contact (``coupling="on"`` with ``gel_geom``)
in real MuJoCo: the gel's force carried by the constraint rows of the contacts between the
gel's geom and the bodies pressing it, taken implicitly in MuJoCo's solve. A ball resting
on the gel settles where the gel carries its weight, for bodies far too light for the
explicit coupling, and MuJoCo's contact force is the gel's; a heavy ball gains no energy;
the coupled gripper lifts every object with the gels alone; a restored state replays;
bad configurations fail naming the attribute."""


import mujoco
import numpy as np
import pytest

import tacrom
from conftest import ROOT
from tacrom.envs import gripper
from test_coupling import MASS, R, G, thrown
from test_state import STATE

REST = (ROOT / "examples" / "rest.xml").read_text()


def implicit_xml(mass: float = MASS, **config: str) -> str:
    """examples/rest.xml with the sensor's pad as the gel's geom: its face on the gel's
    surface, the ball colliding with it, ``gel_geom="pad"``."""
    xml = REST.replace('contype="0" conaffinity="0"', "").replace(
        'size="0.015 0.015 0.002" pos="0 0 -0.006"', 'size="0.015 0.015 0.002" pos="0 0 -0.002"'
    )
    config = {"gel_geom": "pad", **config}
    entries = "".join(f'\n      <config key="{k}" value="{v}"/>' for k, v in config.items())
    xml = xml.replace('<config key="coupling" value="on"/>', '<config key="coupling" value="on"/>' + entries)
    return xml.replace('mass="0.02"', f'mass="{mass}"')


def unstable(data) -> int:
    """MuJoCo's count of unstable accelerations since the data's last reset (after each it
    resets the data, so the values it leaves are finite again)."""
    return int(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)


def contact_force(model, data, geom: str) -> np.ndarray:
    """The total force (world frame) of MuJoCo's contacts with ``geom`` on the other geom."""
    g = model.geom(geom).id
    total = np.zeros(3)
    f6 = np.zeros(6)
    for i in range(data.ncon):
        c = data.contact[i]
        if g not in (c.geom[0], c.geom[1]) or c.efc_address < 0:
            continue
        mujoco.mj_contactForce(model, data, i, f6)
        world = c.frame.reshape(3, 3).T @ f6[:3]
        # The force acts on the second geom along the frame; on the first, opposite.
        total += world if c.geom[0] == g else -world
    return total


@pytest.mark.parametrize("mass", [0.0002, 0.02, 0.1])
def test_a_ball_settles_where_the_gel_carries_its_weight(mass, capfd):
    """After 0.6 s the ball rests (below 1e-4 m/s): the gel's force and MuJoCo's contact
    force on it each equal its weight within 1 % (the solver's tolerance), and the depth
    The 0.2 g ball's stiffness ratio ``k h^2 / m`` is about 12: the explicit coupling warns
    and cannot hold it; no warning here."""
    model = mujoco.MjModel.from_xml_string(implicit_xml(mass))
    data = mujoco.MjData(model)
    for _ in range(300):
        mujoco.mj_step(model, data)
    weight = mass * G
    gel = tacrom.outputs(model, data, "touch")["force"][2]
    carried = contact_force(model, data, "pad")[2]
    assert abs(gel - weight) <= 0.01 * weight, (gel, weight)
    assert abs(carried - weight) <= 0.01 * weight, (carried, weight)
    assert abs(data.qvel[2]) < 1e-4, data.qvel[2]
    err = capfd.readouterr().err
    assert "tacrom" not in err, err


def test_it_rests_on_the_gels_static_curve():
    """On the linear gel without friction the gel's force depends on the ball's pose alone:
    the depth the 20 g ball settles at is where the gel, pressed there from rest (the ball
    a mocap body, no coupling), carries its weight, within 0.5 %."""
    model = mujoco.MjModel.from_xml_string(implicit_xml(solver="linear"))
    data = mujoco.MjData(model)
    for _ in range(300):
        mujoco.mj_step(model, data)
    depth = R - data.qpos[2]
    still = implicit_xml(solver="linear").replace('<config key="coupling" value="on"/>', "")
    still = still.replace('<config key="gel_geom" value="pad"/>', "").replace("<freejoint/>", "")
    still = still.replace('<body name="ball" pos="0 0 0.0051">', f'<body name="ball" mocap="true" pos="0 0 {R - depth}">')
    m2 = mujoco.MjModel.from_xml_string(still)
    d2 = mujoco.MjData(m2)
    mujoco.mj_forward(m2, d2)
    pressed = tacrom.outputs(m2, d2, "touch")["force"][2]
    weight = MASS * G
    assert abs(pressed - weight) <= 0.005 * weight, (depth, pressed, weight)


@pytest.mark.parametrize("mass", [0.5, 2.0])
def test_a_heavy_ball_thrown_at_the_gel_gains_no_energy(mass):
    """Balls of 0.5 and 2 kg meeting the gel at 0.63 m/s (a 2 cm drop) crush it to its
    base within a few steps: backward Euler on the gel's stiffness gives back less than
    it took (the explicit coupling needed a passivity bound for this), nothing is NaN."""
    start, most, least = thrown(implicit_xml(mass), mass, 40)
    assert most <= start * 1.001, (start, most)
    assert least < 0.5 * start, "the ball never pressed the gel"


@pytest.mark.parametrize("obj", gripper.OBJECTS)
def test_the_coupled_gripper_lifts_each_object_on_its_gels(obj, capfd):
    """``tacrom/GripperLift-v1`` with both gels coupled (the default physics, rom on the
    linear gel, at the 2 ms step): descend, close, lift. The object rises past the
    target and the episode succeeds; the gels carry it: MuJoCo's contact force on each
    pad is that fingertip's gel force along the squeeze (within 5 %: the rows add the
    gel's Kelvin-Voigt damping of what motion remains), the pads' contacts together carry
    the object's weight (within 5 %: the lift is still slowing), the backings behind the
    gels touch nothing, and no warning is given (nor did MuJoCo find an acceleration
    unstable)."""
    env = gripper.GripperLiftEnv(physics="rom", object=obj, coupling=True)
    env.reset(seed=0)
    cycle = [(0.0, -1.0, -1.0)] * 15 + [(0.0, -1.0, 1.0)] * 10 + [(0.0, 0.5, 1.0)] * 12
    for a in cycle:
        obs, _, _, _, info = env.step(np.array(a, dtype=np.float32))
    assert info["is_success"], info
    assert info["object_height"] >= env.lift_target, info
    m, d = env.model, env.data
    weight = m.body(obj).mass[0] * G
    lifted = sum(contact_force(m, d, pad)[2] for pad, _, _ in gripper.PADS)
    assert abs(lifted - weight) <= 0.05 * weight, (lifted, weight)
    for gel, (pad, finger, side) in zip(info["gel_force"][:, 2], gripper.PADS):
        # The gel pushes the object away from the pad: along +x from the left pad.
        carried = side * contact_force(m, d, pad)[0]
        assert gel > 1.0 and abs(carried - gel) <= 0.05 * gel, (pad, carried, gel)
        backing = m.geom(f"{pad}_backing").id
        touching = [i for i in range(d.ncon) if backing in (d.contact[i].geom[0], d.contact[i].geom[1])]
        assert not touching, (pad, "the object reached the backing")
    assert unstable(d) == 0
    err = capfd.readouterr().err
    assert "tacrom" not in err, err


def test_the_coupled_box_at_a_10_ms_step_is_lifted_and_held_still():
    """The grasp of the box at a physics step of 10 ms (seed 0; the environment's step kept
    at 40 ms), then 15 steps held up. The box stands 4 degrees off the pads and MuJoCo's
    contacts lie on its leading edges, 4.6 mm from the gel's centre of pressure. Where a
    couple on the side made up that lever, explicitly, it spun the box 15 degrees in one
    step, MuJoCo reset the data as unstable and the box was thrown; with the rows moved to
    where the gel presses the box was lifted past the target, but the gels then bounced it
    between the fingers by millimetres a step at up to 100 N and more: the fingers (51 g,
    damped at 40 N s/m) were damped by MuJoCo's Euler step after its constraint solve,
    which took them for free bodies. With the drives' inertia on the fingers' joints
    (armature, `examples/gripper.xml`) the box is lifted, no step unstable, every
    observation finite, and held still: over the last 10 held steps it moves less than
    10 um a step against the left finger and both gels squeeze it alike, within 10 % of
    the quiet hold's 3.6 N. (Over five seeds and the three objects every hold at 2 to 10 ms
    is still: `examples/coupled_steps.py`, `docs/rl.md`.)"""
    env = gripper.GripperLiftEnv(physics="rom", object="box", coupling=True, frame_skip=4)
    env.model.opt.timestep = 0.01
    import warnings

    # Up to 10 ms a coupled episode does not warn (the next test).
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env.reset(seed=0)
    m, d = env.model, env.data
    box, finger = m.body("box").id, m.body("left_finger").id
    cycle = [(0.0, -1.0, -1.0)] * 15 + [(0.0, -1.0, 1.0)] * 10 + [(0.0, 0.5, 1.0)] * 27
    held, squeeze = [], []
    for i, a in enumerate(cycle):
        obs, _, _, _, info = env.step(np.array(a, dtype=np.float32))
        assert all(np.isfinite(v).all() for v in obs.values())
        if i == 36:
            assert info["is_success"], info
            assert info["object_height"] >= env.lift_target, info
        if i >= len(cycle) - 11:
            frame = d.xmat[finger].reshape(3, 3)
            held.append(frame.T @ (d.xpos[box] - d.xpos[finger]))
            squeeze.append(info["gel_force"][:, 2].copy())
    assert unstable(d) == 0
    assert info["is_success"], info
    moved = np.abs(np.diff(np.array(held), axis=0)).max()
    assert moved < 10e-6, f"the held box moves {moved * 1e6:.1f} um a step"
    squeeze = np.array(squeeze)
    assert np.all(np.abs(squeeze - 3.57) <= 0.1 * 3.57), squeeze


def test_a_joint_damped_past_its_inertia_within_a_step_is_warned_about(capfd):
    """The coupled gripper's fingers without their drives' inertia (armature 0: 51 g on a
    joint damped at 40 N s/m) at an 8 ms step: MuJoCo's Euler step takes that damping
    after its constraint solve, 6.3 times the finger's inertia over the step, and the
    gels bounced held objects between the fingers (docs/rl.md, "A long physics step: the
    fingers' damping, taken after the solve"). Each sensor warns once, naming itself,
    `gel_geom`, its finger's joint, the ratio, the step and the remedy. At 2 ms (1.6) and
    with the scene's armature at 10 ms (1.6) nothing is said."""
    import warnings

    cases = [(0.008, 0.0, True), (0.002, 0.0, False), (0.01, None, False)]
    for step, armature, warned in cases:
        env = gripper.GripperLiftEnv(
            physics="rom", object="box", coupling=True, frame_skip=max(1, round(0.04 / step))
        )
        env.model.opt.timestep = step
        if armature is not None:
            for joint in ("left", "right"):
                env.model.dof_armature[env.model.joint(joint).dofadr[0]] = armature
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env.reset(seed=0)
        for a in [(0.0, -1.0, -1.0)] * 15 + [(0.0, -1.0, 1.0)] * 4:
            env.step(np.array(a, dtype=np.float32))
        env.close()
        err = capfd.readouterr().err
        said = [line for line in err.splitlines() if "damped" in line and "inertia" in line]
        if not warned:
            assert not said, (step, said)
            continue
        for sensor, joint in (("left_touch", "left"), ("right_touch", "right")):
            mine = [line for line in said if f"sensor '{sensor}'" in line]
            assert len(mine) == 1, (sensor, said)
            w = mine[0]
            assert "attribute 'gel_geom'" in w and f"joint '{joint}'" in w, w
            assert "6.3 times its inertia over the 8.0 ms physics step" in w, w
            assert "armature" in w and "shorter timestep" in w, w


def test_a_coupled_episode_beyond_10_ms_warns_that_the_hold_may_bounce():
    """At physics steps beyond 10 ms the coupled grasp's gels can bounce the held object
    between the fingers by millimetres (13.3 ms: 13 of 15 holds still; 20 ms: none;
    docs/rl.md, "A long physics step: the fingers' damping, taken after the solve"). A
    coupled episode reset at such a step warns, naming the step and the limit; at 2, 6 and
    10 ms it does not, nor does an uncoupled one at 20 ms (its rigid pads were not measured
    to bounce)."""
    import warnings

    env = gripper.GripperLiftEnv(physics="rom", object="box", coupling=True)
    for step in (0.002, 0.006, 0.01):
        env.model.opt.timestep = step
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            env.reset(seed=0)
    env.model.opt.timestep = 0.0133
    with pytest.warns(RuntimeWarning, match=r"13.3 ms: beyond 10 ms .* at most 10 ms"):
        env.reset(seed=0)
    env.close()
    rigid = gripper.GripperLiftEnv(physics="rom", object="box")
    rigid.model.opt.timestep = 0.02
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rigid.reset(seed=0)
    rigid.close()


def test_a_restored_state_replays_the_coupled_gel_between_solves_bit_for_bit():
    """The ball thrown at the gel with the sensors off (the passive stage follows the last
    solve and solves again where the ball moved past its bound): the state after 5 steps
    given to a new MjData replays 25 more steps to the last bit. The state holds MuJoCo's
    warm start too (``mjSTATE_WARMSTART``): the ball's contact is solved by MuJoCo's
    iterative solver, whose last bits depend on where it starts."""
    model = mujoco.MjModel.from_xml_string(implicit_xml())
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SENSOR
    data = mujoco.MjData(model)
    data.qvel[2] = -0.1
    for _ in range(5):
        mujoco.mj_step(model, data)
    state = STATE | mujoco.mjtState.mjSTATE_WARMSTART
    saved = np.empty(mujoco.mj_stateSize(model, state))
    mujoco.mj_getState(model, data, saved, state)

    def run(d):
        out = []
        for _ in range(25):
            mujoco.mj_step(model, d)
            out.append(np.concatenate([d.qpos, d.qvel, d.efc_force[: d.nefc].sum(keepdims=True)]))
        return np.array(out)

    original = run(data)
    restored = mujoco.MjData(model)
    mujoco.mj_setState(model, restored, saved, state)
    np.testing.assert_array_equal(original, run(restored))
    assert np.abs(original[:, 2] - original[0, 2]).max() > 1e-5, "the ball did not move"


def test_the_discrete_integrator_is_refused_and_throws_nothing(capfd):
    """MuJoCo's discrete integrator solves the constraints in its own effective metric, where
    the rows the coupling writes are not the gel's backward Euler: the 20 g ball resting on
    the gel was thrown 4 m up within 0.6 s. The coupling now refuses that integrator,
    naming the sensor, the attribute and the integrator, and the gel's geom acts as a rigid
    contact: after 0.6 s the ball rests on it, within a millimetre of where the gel holds
    it under Euler's integrator."""
    model = mujoco.MjModel.from_xml_string(implicit_xml())
    data = mujoco.MjData(model)
    for _ in range(300):
        mujoco.mj_step(model, data)
    held = data.qpos[2]
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_DISCRETE
    mujoco.mj_resetData(model, data)
    capfd.readouterr()
    for _ in range(300):
        mujoco.mj_step(model, data)
    assert np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()
    assert abs(data.qpos[2] - held) < 1e-3, (data.qpos[2], held)
    assert abs(data.qvel[2]) < 1e-3, data.qvel[2]
    err = capfd.readouterr().err
    assert "sensor 'touch'" in err and "gel_geom" in err and "discrete integrator" in err, err


@pytest.mark.parametrize(
    "change, value, reason",
    [
        (dict(coupling="off"), "pad", 'needs coupling="on"'),
        (dict(gel_geom="nowhere"), "nowhere", "no geom of that name"),
        (dict(gel_geom="ball"), "ball", "not on the sensor's body"),
    ],
)
def test_a_bad_gel_geom_fails_at_load_naming_it(change, value, reason):
    xml = implicit_xml()
    if "coupling" in change:
        xml = xml.replace('<config key="coupling" value="on"/>', '<config key="coupling" value="off"/>')
    else:
        xml = xml.replace('<config key="gel_geom" value="pad"/>', f'<config key="gel_geom" value="{value}"/>')
    with pytest.raises(ValueError) as e:
        mujoco.MjModel.from_xml_string(xml)
    message = str(e.value)
    assert "'touch'" in message and "gel_geom" in message and value in message and reason in message, message


@pytest.mark.parametrize(
    "pad, ball, warns",
    [
        ("", "", False),
        ('condim="4" ', "", True),
        ("", 'condim="6" ', True),
        ('condim="3" priority="1" ', 'condim="4" ', False),
        ("", 'condim="4" contype="2" conaffinity="2" ', False),
    ],
)
def test_torsional_friction_on_the_gels_contacts_is_named_at_load(pad, ball, warns, capfd):
    """A gel's geom whose contacts with an indenter get torsional friction rows (the
    pair's condim above 3: the higher priority's, else the larger) is named at load, with
    the sensor, the geom, the pair's condim and the remedy: MuJoCo's soft torsional row,
    beside the gel's own resistance to a turn, let the gripper's held hexagon turn on for
    2 s. condim 3 (the default), a priority above the indenter's, or collision masks that
    keep the two apart, is quiet."""
    xml = implicit_xml().replace('<geom name="pad" ', f'<geom name="pad" {pad}')
    xml = xml.replace('<geom name="ball" ', f'<geom name="ball" {ball}')
    mujoco.MjModel.from_xml_string(xml)
    err = capfd.readouterr().err
    if warns:
        assert "'touch'" in err and "gel_geom 'pad'" in err and "'ball'" in err, err
        assert "condim" in err and "priority" in err, err
    else:
        assert "tacrom" not in err, err


def test_a_whole_grasp_cycle_puts_down_and_lets_go_without_a_warning(capfd):
    """Catches: a gel let go within a frame whose lagged forces never settle. The whole
    grasp cycle of ``examples/rl_throughput.py`` (descend, close, lift, hold, put down,
    open) on the coupled gels, seed 1 (it draws the cylinder): while the fingers open, the passive
    stage solves each gel again as it leaves the object, from newtons to a touch a
    micron deep within one frame; the linear gel's lagged normal forces settle against
    the frame's load at its start, and no frame fails to converge (it warned, "gel did
    not reach equilibrium", before). The object ends back on the table, both gels clear."""
    import sys

    sys.path.insert(0, str(ROOT / "examples"))
    from rl_throughput import GRIPPER_CYCLE

    env = gripper.GripperLiftEnv(physics="coarse", coupling=True, sensor_config={"solver": "linear"})
    env.reset(seed=1)
    lifted = False
    for a in GRIPPER_CYCLE:
        obs, _, _, _, info = env.step(np.array(a, dtype=np.float32))
        lifted |= info["is_success"]
    assert lifted, info
    assert abs(info["object_height"]) < 1e-3 and (info["gel_force"][:, 2] == 0).all(), info
    assert unstable(env.data) == 0
    err = capfd.readouterr().err
    assert "tacrom" not in err, err


def test_a_held_hexagon_comes_to_rest_on_its_gels():
    """The lifted hexagon of ``examples/rl_throughput.py``'s episode (seed 0), whose
    contacts with the pads MuJoCo makes at a changing few of its face's corners, comes to
    rest while held: over the last ten of 50 held steps it moves less than 0.1 um a step
    and the gels' forces do not change (no solve). It rests from about step 57 of the
    cycle. Catches MuJoCo's torsional friction on the gel's contacts (the pads' condim
    4, which `couple_pads` now makes 3): its soft row let the hexagon turn on in the grasp
    by a tenth of what was left at each step, until about step 77 (the gels solved again
    until step 92). The gel's force lands at its centre of
    pressure wherever MuJoCo's contacts lie (`gel_contacts::carry`); where the contacts'
    own centre stood in, each change of MuJoCo's contacts turned the hexagon, and the
    grasp stick-slipped by 5 to 9 um every few steps for as long as it was held."""
    env = gripper.GripperLiftEnv(physics="rom", object="random", coupling=True)
    _, info = env.reset(seed=0)
    assert info["object"] == "hexagon", info
    body = env.model.body("hexagon").id
    cycle = [(0.0, -1.0, -1.0)] * 15 + [(0.0, -1.0, 1.0)] * 10 + [(0.0, 0.5, 1.0)] * 50
    moved, forces = [], []
    before = env.data.xpos[body].copy()
    for a in cycle:
        _, _, _, _, info = env.step(np.array(a, dtype=np.float32))
        now = env.data.xpos[body].copy()
        moved.append(np.linalg.norm(now - before))
        forces.append(info["gel_force"].copy())
        before = now
    assert info["is_success"], info
    assert max(moved[-10:]) < 1e-7, moved[-10:]
    assert all(np.array_equal(f, forces[-1]) for f in forces[-10:]), forces[-10:]
