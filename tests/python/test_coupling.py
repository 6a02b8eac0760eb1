"""The gel that pushes back (``coupling="on"``) in real MuJoCo: a ball resting on the gel
settles where the gel's force equals its weight, on the gel's own static force-depth
curve; it settles without oscillation and an undamped gel gains no energy; action equals
reaction; MjData in threads equal MjData one after the other; bad configurations fail."""

import math

import mujoco
import numpy as np
import pytest

import tacrom
from conftest import ROOT, in_threads

REST = (ROOT / "examples" / "rest.xml").read_text()
R, MASS, G = 0.005, 0.02, 9.81


def rest_xml(**config: str) -> str:
    """The rest example with sensor configuration entries replaced or added."""
    xml = REST
    for key, value in config.items():
        entry = f'<config key="{key}" value="'
        if entry in xml:
            start = xml.index(entry) + len(entry)
            xml = xml[:start] + value + xml[xml.index('"', start) :]
        else:
            xml = xml.replace("</plugin>\n  </sensor>", f'  {entry}{value}"/>\n    </plugin>\n  </sensor>')
    return xml


def drop(xml: str, seconds: float, mass: float = MASS):
    """Drops the ball from 0.1 mm above the gel; returns times, heights and vertical
    velocities of its centre and the sensor's force output at each step."""
    model = mujoco.MjModel.from_xml_string(xml.replace('mass="0.02"', f'mass="{mass}"'))
    data = mujoco.MjData(model)
    steps = int(round(seconds / model.opt.timestep))
    z, v, f = np.empty(steps), np.empty(steps), np.empty(steps)
    for k in range(steps):
        mujoco.mj_step(model, data)
        z[k], v[k] = data.qpos[2], data.qvel[2]
        f[k] = tacrom.outputs(model, data, "touch")["force"][2]
    return model, data, z, v, f


def static_force(depth: float) -> float:
    """The gel's force on the ball held still ``depth`` into the gel from rest (no
    coupling, the ball a mocap body): the gel's own static force-depth curve."""
    xml = rest_xml(coupling="off").replace("<freejoint/>", "").replace(
        '<body name="ball" pos="0 0 0.0051">', f'<body name="ball" mocap="true" pos="0 0 {R - depth}">'
    )
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return tacrom.outputs(model, data, "touch")["force"][2]


def test_a_resting_ball_settles_where_the_gel_carries_its_weight():
    """After 0.6 s the ball has settled: the gel's force equals its weight (within 1 %,
    the solver's tolerance), and the depth it settled at is where the gel's static
    force-depth curve, pressed from rest, carries that weight (within 2 %: the two solves
    take different paths to the same equilibrium, each to a 3e-3 tolerance). The depth
    is also within 15 % of the bonded-layer Hertz solution's (the coarse gel's force is
    up to 11 % high at these depths, see the mpm benchmark)."""
    _, _, z, _, f = drop(REST, 0.6)
    depth = R - z[-1]
    weight = MASS * G
    assert abs(f[-1] - weight) <= 0.01 * weight, (f[-1], weight)
    assert abs(static_force(depth) - weight) <= 0.02 * weight, (depth, static_force(depth), weight)
    from test_gel import hertz_bonded

    # Depth at which the Hertz force equals the weight, by bisection.
    lo, hi = 1e-6, 2e-3
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if hertz_bonded(1.19e5, 0.43, R, mid, 0.004) < weight else (lo, mid)
    assert abs(depth - lo) <= 0.15 * lo, (depth, lo)


@pytest.mark.parametrize("mass", [0.002, 0.02, 0.1])
def test_it_settles_without_oscillation_for_light_and_heavy_bodies(mass, capfd):
    """Balls of 2, 20 and 100 g at MuJoCo's default 2 ms step: after 0.1 s the ball's
    speed stays below 0.5 mm/s and does not grow beyond the noise of the solver's
    tolerance (a 2 g ball jitters at up to 0.25 mm/s, half a micrometre per step), and it
    rests at the depth where the gel carries it."""
    _, _, z, v, f = drop(REST, 0.5, mass)
    after = np.abs(v[50:])
    assert after.max() < 5e-4, after.max()
    halves = np.array_split(after, 2)
    assert halves[1].max() <= max(halves[0].max(), 3e-4), [h.max() for h in halves]
    assert abs(f[-1] - mass * G) <= 0.02 * mass * G + 1e-4, (f[-1], mass * G)
    # Stable, so no stability warning (stiffness * step^2 / mass is at most 1.2 here).
    assert "unstable" not in capfd.readouterr().err


def test_an_undamped_gel_gains_no_energy():
    """With ``damping="0"`` the ball bounces on the gel's elastic force alone: over 0.6 s
    its largest speed per 0.1 s window never grows (the explicit coupling adds no energy),
    and it keeps bouncing (the damping is what settles it)."""
    _, _, _, v, _ = drop(rest_xml(damping="0"), 0.6)
    peaks = [np.abs(w).max() for w in np.array_split(v, 6)]
    assert all(b <= a * 1.02 for a, b in zip(peaks, peaks[1:])), peaks
    assert peaks[-1] > 0.01, peaks


def thrown(xml: str, mass: float, steps: int) -> tuple[float, float, float]:
    """The ball of ``xml`` (mass ``mass``) thrown at the gel at 0.63 m/s (a 2 cm drop) for
    ``steps`` steps, everything checked finite at each: its mechanical energy at the start,
    its largest and its smallest."""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.qvel[2] = -math.sqrt(2 * G * 0.02)

    def energy():
        return 0.5 * mass * data.qvel[2] ** 2 + mass * G * (data.qpos[2] - R)

    start, most, least = energy(), -np.inf, np.inf
    for _ in range(steps):
        mujoco.mj_step(model, data)
        most, least = max(most, energy()), min(least, energy())
        assert np.isfinite(data.sensordata).all() and np.isfinite(data.qfrc_passive).all()
        assert np.isfinite(data.qacc).all()
    return start, most, least


@pytest.mark.parametrize("mass", [0.5, 2.0])
def test_a_heavy_ball_thrown_at_the_gel_gains_no_energy_and_is_warned_about(mass, capfd):
    """Balls of 0.5 and 2 kg meeting the gel at 0.63 m/s (a 2 cm drop) at the 2 ms step
    crush the 4 mm gel within two steps and reach its base. An explicit coupling gave the
    0.5 kg ball back ten times what it took (0.099 J in, 1.01 J out): the gel is passive,
    so the ball's mechanical energy never exceeds its start (within 1 %: the energy the
    gel holds is estimated after each step, trapezoidally, and the force bounded from the
    predicted displacement, with gravity left out of the prediction), nothing is NaN, and
    the sensor says that the gel cannot hold the ball."""
    # Twelve steps: the 0.5 kg ball had gained energy by the fifth.
    start, most, least = thrown(REST.replace('mass="0.02"', f'mass="{mass}"'), mass, 12)
    assert most <= start * 1.01, (start, most)
    assert least < 0.5 * start, "the ball never pressed the gel"
    err = capfd.readouterr().err
    assert "reaches the gel's base" in err, err


def test_without_coupling_the_ball_falls_through():
    """The same scene with ``coupling="off"``: nothing holds the ball (its MuJoCo contact is
    off), so it falls through the gel while the sensor still sees it."""
    _, _, z, _, f = drop(rest_xml(coupling="off"), 0.1)
    assert z[-1] < -0.02, z[-1]


def test_action_equals_reaction():
    """A free sensor body and a free ball, no gravity, the ball thrown at the gel: the
    coupling applies equal and opposite wrenches, so the total momentum stays at its
    initial value to round-off while the ball pushes the sensor away."""
    xml = (
        REST.replace('<option timestep="0.002"/>', '<option timestep="0.002" gravity="0 0 0"/>')
        .replace('<body name="sensor" pos="0 0 0">', '<body name="sensor" pos="0 0 0">\n      <freejoint/>')
        .replace('contype="0" conaffinity="0"', 'contype="0" conaffinity="0"', 1)
    )
    xml = xml.replace('<geom name="pad" type="box"', '<geom name="pad" type="box" mass="0.05" contype="0" conaffinity="0"')
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    ball = model.body("ball").id
    data.qvel[model.jnt_dofadr[model.body_jntadr[ball]] + 2] = -0.05
    mujoco.mj_forward(model, data)

    def momentum():
        p = np.zeros(3)
        for b in range(1, model.nbody):
            v = np.zeros(6)
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, b, v, 0)
            p += model.body_mass[b] * v[3:]
        return p

    start = momentum()
    pushed = 0.0
    for _ in range(150):
        mujoco.mj_step(model, data)
        pushed = max(pushed, tacrom.outputs(model, data, "touch")["force"][2])
    assert pushed > 0.02, pushed
    end = momentum()
    sensor = model.body("sensor").id
    assert data.qvel[model.jnt_dofadr[model.body_jntadr[sensor]] + 2] < -0.005, "the sensor was not pushed"
    assert np.abs(end - start).max() <= 1e-9, (start, end)


def test_mjdata_in_threads_equal_one_after_the_other():
    """Two MjData of the coupled scene stepped in two threads give bit for bit the
    trajectories of the same two stepped one after the other."""
    model = mujoco.MjModel.from_xml_string(REST)

    def run(offset):
        data = mujoco.MjData(model)
        data.qpos[0] = offset
        out = []
        for _ in range(60):
            mujoco.mj_step(model, data)
            out.append(data.qpos.copy())
        return np.array(out)

    offsets = [0.0, 0.002]
    serial = [run(o) for o in offsets]
    threaded = in_threads(run, offsets)
    for a, b in zip(serial, threaded):
        assert np.array_equal(a, b)


def test_the_coupling_runs_where_sensors_do_not():
    """With sensors disabled (``mjDSBL_SENSOR``, as a fast RL loop might) and with the RK4
    integrator (whose inner stages skip sensors) the gel still holds the ball up."""
    for xml in (
        REST.replace('<option timestep="0.002"/>', '<option timestep="0.002"><flag sensor="disable"/></option>'),
        REST.replace('<option timestep="0.002"/>', '<option timestep="0.002" integrator="RK4"/>'),
    ):
        _, _, z, _, _ = drop(xml, 0.3)
        depth = R - z[-1]
        assert 0.3e-3 < depth < 0.6e-3, depth


@pytest.mark.parametrize(
    "config, attribute, reason",
    [
        (dict(physics="rigid", outputs="depth"), "coupling", "needs a gel model"),
        (dict(damping="-1"), "damping", "must be in [0, 1]"),
        (dict(coupling="yes"), "coupling", "expected on or off"),
    ],
)
def test_bad_coupling_configurations_fail_at_load(config, attribute, reason):
    with pytest.raises(ValueError) as e:
        mujoco.MjModel.from_xml_string(rest_xml(**config))
    message = str(e.value)
    assert "'touch'" in message and attribute in message and reason in message, message


def test_a_body_too_light_for_the_time_step_is_warned_about(capfd):
    """A 0.2 g ball on the gel at the 2 ms step: the gel's stiffness (about 600 N/m) times
    the step squared over the mass is about 12, beyond the explicit coupling's stable
    range, and the sensor says so, naming the body and the ratio."""
    drop(REST, 0.05, 0.0002)
    err = capfd.readouterr().err
    assert "coupling may be unstable" in err and "body 'ball'" in err, err


def test_evaluating_a_state_twice_keeps_the_damping_capped():
    """A loop that calls ``mj_forward`` before each ``mj_step`` (as viewers and wrappers
    do) evaluates each state twice at the same time: the second evaluation keeps the first
    one's damping and its cap, so the 2 g ball still settles."""
    model = mujoco.MjModel.from_xml_string(REST.replace('mass="0.02"', 'mass="0.002"'))
    data = mujoco.MjData(model)
    speeds = []
    for _ in range(250):
        mujoco.mj_forward(model, data)
        mujoco.mj_step(model, data)
        speeds.append(abs(data.qvel[2]))
    assert max(speeds[50:]) < 5e-4, max(speeds[50:])
    assert 0 < R - data.qpos[2] < 0.2e-3, data.qpos[2]
