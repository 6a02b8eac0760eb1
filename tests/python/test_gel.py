"""The coarse MPM gel through the real `mujoco` Python package: physics sanity, state
handling per MjData, determinism across solver threads and Python threads."""

import math

import mujoco
import numpy as np

import tacrom
from conftest import evaluate, in_threads, with_config

COARSE = dict(physics="coarse", outputs="depth force contact", resolution="64 48")


def hertz_bonded(e, nu, r, d, h):
    """Force (N) of a frictionless rigid sphere pressed ``d`` into an elastic layer of
    thickness ``h`` bonded to a rigid base: Hertz times the bonded-layer correction of
    Dimitriadis et al. 2002 (Biophys. J. 82, Eq. 12). Written here independently of the
    Rust code it checks."""
    es = e / (1 - nu * nu)
    a0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu * nu) / (1 - nu)
    b0 = (0.6387 - 1.0277 * nu + 1.5164 * nu * nu) / (1 - nu)
    c = math.sqrt(r * d) / h
    pi = math.pi
    bracket = (
        1
        - 2 * a0 / pi * c
        + 4 * a0 * a0 / pi**2 * c * c
        - 8 / pi**3 * (a0**3 + 4 * pi * pi * b0 / 15) * c**3
        + 16 * a0 / pi**4 * (a0**3 + 3 * pi * pi * b0 / 5) * c**4
    )
    return 4 * es / 3 * math.sqrt(r) * d**1.5 * bracket


def test_coarse_press_physics(press_xml):
    """The gel's own physics, not the image's bounds: the force of a frictionless sphere
    (R = 5 mm, the press example) against the bonded-layer Hertz solution, and the sag
    beyond the contact patch that no rigid model has."""
    model = mujoco.MjModel.from_xml_string(with_config(press_xml, **COARSE, friction="0"))
    data = mujoco.MjData(model)
    forces = []
    for d in (0.2e-3, 0.3e-3, 0.4e-3, 0.5e-3):
        out = evaluate(model, data, d)
        depth, force, contact = out["depth"], out["force"], out["contact"]
        assert depth.shape == (48, 64) and contact.shape == (48, 64) and force.shape == (3,)
        assert np.all(np.isfinite(depth)) and depth.min() >= 0.0 and depth.max() <= 0.004
        # Hertz on the bonded 4 mm layer. From 0.2 mm the contact radius sqrt(2 R d) is at
        # least one coarse cell (1.4 mm); there the coarse grid's discretisation error is
        # +4 to +12 % at tolerance 3e-3 (measured; +/-6 % at 1e-4, so the rest is the
        # solve's tolerance), within the 15 % asserted. At 0.1 mm (contact radius 1 mm,
        # under one cell) it is +37 %: not asserted.
        f_ref = hertz_bonded(1.19e5, 0.43, 0.005, d, 0.004)
        assert abs(force[2] / f_ref - 1) < 0.15, (d, force[2], f_ref)
        # Frictionless and centred: no lateral force beyond the solve's tolerance.
        assert abs(force[0]) < 0.01 * force[2] and abs(force[1]) < 0.01 * force[2]
        # The gel sags beyond the contact patch (a rigid model would not).
        assert np.count_nonzero((contact == 0) & (depth > 1e-6)) > 0
        # Centred press: the image is mirror symmetric to solver tolerance (5 % of peak).
        assert np.abs(depth - depth[:, ::-1]).max() < 0.05 * d
        assert np.abs(depth - depth[::-1, :]).max() < 0.05 * d
        forces.append(force[2])
    assert 0 < forces[0] < forces[1] < forces[2] < forces[3]


def test_newton_solver_through_mujoco(press_xml):
    """``solver="newton"`` on the coarse gel: the 5 mm sphere's force against the
    bonded-layer Hertz solution at 0.3 and 0.5 mm (within 10 %: measured +4 % and -4 % in
    the mpm benchmark), and a sphere of radius 0.5 mm, which reaches between the coarse
    gel's surface particles (0.7 mm apart), loads the gel at every depth from 0.1 mm: its
    force grows with depth and stays within 2.5 times that of a 0.5 mm grid (the coarse
    grid cannot bend the surface as sharply as the contact asks; measured 1.6 to 2.1
    times)."""
    model = mujoco.MjModel.from_xml_string(
        with_config(press_xml, physics="coarse", solver="newton", outputs="force",
                    resolution="32 24", friction="0")
    )
    data = mujoco.MjData(model)
    for d in (0.3e-3, 0.5e-3):
        f_ref = hertz_bonded(1.19e5, 0.43, 0.005, d, 0.004)
        force = evaluate(model, data, d)["force"][2]
        assert abs(force / f_ref - 1) < 0.10, (d, force, f_ref)
    small = press_xml.replace(
        '<geom name="ball" type="sphere" size="0.005"', '<geom name="ball" type="sphere" size="0.0005"'
    ).replace('<body name="indenter" pos="0 0 0.005">', '<body name="indenter" pos="0 0 0.0005">')

    def forces(**config):
        m = mujoco.MjModel.from_xml_string(
            with_config(small, outputs="force", resolution="32 24", friction="0", **config)
        )
        d = mujoco.MjData(m)
        return [evaluate(m, d, depth)["force"][2] for depth in (0.1e-3, 0.2e-3, 0.3e-3, 0.4e-3)]

    coarse = forces(physics="coarse", solver="newton")
    finer = forces(physics="coarse", dx="0.0005")
    assert 0 < coarse[0] < coarse[1] < coarse[2] < coarse[3], coarse
    for c, f in zip(coarse, finer):
        assert 0.5 * f < c < 2.5 * f, (coarse, finer)


def test_linear_solver_through_mujoco(press_xml):
    """``solver="linear"`` on the coarse gel (small-strain elasticity about the undeformed
    gel, frictionless contact solved on its surface compliance): the 5 mm sphere's force
    against the bonded-layer Hertz solution at 0.3 and 0.5 mm within 10 % (measured +7.2
    and +3.5 % in the mpm benchmark), a centred press's image mirror symmetric to
    round-off, and
    the answer a function of the pose alone: the same press reached through a deeper one
    gives the same outputs bit for bit."""
    model = mujoco.MjModel.from_xml_string(
        with_config(press_xml, physics="coarse", solver="linear", friction="0",
                    outputs="depth force contact", resolution="64 48")
    )
    data = mujoco.MjData(model)
    first = {}
    for d in (0.3e-3, 0.5e-3):
        f_ref = hertz_bonded(1.19e5, 0.43, 0.005, d, 0.004)
        out = evaluate(model, data, d)
        force, depth = out["force"], out["depth"]
        assert abs(force[2] / f_ref - 1) < 0.10, (d, force[2], f_ref)
        assert force[0] == 0 and force[1] == 0
        assert np.abs(depth - depth[:, ::-1]).max() < 1e-9
        assert np.abs(depth - depth[::-1, :]).max() < 1e-9
        first[d] = out
    again = evaluate(model, data, 0.3e-3)
    for name in ("depth", "force", "contact"):
        np.testing.assert_array_equal(again[name], first[0.3e-3][name])


def test_linear_solver_friction_through_mujoco(press_xml):
    """``solver="linear"`` with friction 0.5: the 5 mm sphere pressed 0.3 mm and slid
    sideways. The gel holds it back (a lateral force against the motion) that grows while
    the contact sticks and never exceeds friction times the normal force; slid 1 mm it
    slides, carrying friction times the normal force (within 3 %: the lagged normal
    forces' tolerance and the spread of the points' sliding directions). Frictionless, the
    same slide carries no lateral force at all."""
    slid = press_xml.replace(
        '<joint name="press" type="slide" axis="0 0 -1" range="-0.002 0.003" damping="5"/>',
        '<joint name="press" type="slide" axis="0 0 -1" range="-0.002 0.003" damping="5"/>'
        '<joint name="slide" type="slide" axis="1 0 0"/>',
    )

    def slide(friction, xs):
        model = mujoco.MjModel.from_xml_string(
            with_config(slid, physics="coarse", solver="linear", friction=friction,
                        outputs="force", resolution="32 24")
        )
        data = mujoco.MjData(model)
        out = []
        for x in xs:
            data.qpos[:2] = (0.3e-3, x)
            mujoco.mj_forward(model, data)
            out.append(tacrom.outputs(model, data, "touch")["force"].copy())
        return np.array(out)

    small = slide("0.5", [0.0, 5e-6, 10e-6, 20e-6])
    assert np.all(small[1:, 0] < 0), small
    assert np.all(np.diff(small[:, 0]) < 0), small
    assert np.all(np.abs(small[:, 0]) <= 0.5 * small[:, 2] * 1.001), small
    far = slide("0.5", [0.0, 0.25e-3, 0.5e-3, 0.75e-3, 1e-3])[-1]
    assert abs(-far[0] / (0.5 * far[2]) - 1) < 0.03, far
    frictionless = slide("0", [0.0, 0.25e-3, 0.5e-3])
    assert np.all(frictionless[:, :2] == 0), frictionless


def test_solver_threads_do_not_change_results(press_xml):
    images = []
    for threads in ("1", "2"):
        model = mujoco.MjModel.from_xml_string(with_config(press_xml, **COARSE, threads=threads))
        images.append(evaluate(model, mujoco.MjData(model), 0.35e-3))
    for name in ("depth", "force", "contact"):
        np.testing.assert_array_equal(images[0][name], images[1][name])


def test_python_threads_match_sequential(press_xml):
    model = mujoco.MjModel.from_xml_string(with_config(press_xml, **COARSE))
    depths = [0.2e-3, 0.45e-3]
    sequential = [evaluate(model, mujoco.MjData(model), d)["depth"] for d in depths]
    results = in_threads(lambda d: evaluate(model, mujoco.MjData(model), d)["depth"], depths)
    for a, b in zip(sequential, results):
        np.testing.assert_array_equal(a, b)


def test_rom_through_mujoco(press_xml):
    """The default physics (rom: coarse MPM + ONNX decoder) loads the shipped model and
    runs its decoder: were it to fail and fall back to the coarse surface (with a warning),
    its image would equal coarse's bit for bit; here it must differ. Its image is finite,
    within [0, T] and nearly mirror symmetric for a centred sphere."""
    xml = with_config(press_xml, outputs="depth contact", resolution="64 48")  # physics: default
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    coarse = mujoco.MjModel.from_xml_string(
        with_config(press_xml, physics="coarse", outputs="depth contact", resolution="64 48")
    )
    coarse_data = mujoco.MjData(coarse)
    for d in (0.2e-3, 0.5e-3):
        depth = evaluate(model, data, d)["depth"]
        assert np.all(np.isfinite(depth)) and depth.min() >= 0.0 and depth.max() <= 0.004
        # Not the coarse fallback: the decoder moves the surface by micrometres (measured
        # 19 and 49 um at most at 0.2 and 0.5 mm); 1 um is far above round-off.
        assert np.abs(depth - evaluate(coarse, coarse_data, d)["depth"]).max() > 1e-6
        # The decoder was trained with the lattice's 8 symmetries; measured asymmetry 5.3
        # and 3.3 % of the press depth, asserted within 10 %.
        assert np.abs(depth - depth[:, ::-1]).max() < 0.1 * d
        assert np.abs(depth - depth[::-1, :]).max() < 0.1 * d


def test_rom_bad_model_directory_names_the_attribute(press_xml, tmp_path):
    import pytest

    xml = with_config(press_xml, physics="rom", model=str(tmp_path / "nowhere"))
    with pytest.raises(ValueError) as err:
        mujoco.MjModel.from_xml_string(xml)
    assert "'model'" in str(err.value) and "'touch'" in str(err.value)


def test_small_ball_loads_the_default_coarse_gel(press_xml):
    """A ball of radius 0.5 mm falls between the coarse gel's top particles (0.7 mm
    apart): the relaxation alone gives no force, so a coarse sensor that names no solver
    solves those frames by Newton's method. Its force follows the bonded-layer Hertz
    solution within 25 % (measured +3 and -6 % at these depths, frictionless); naming the
    relaxation keeps its zero."""
    small = press_xml.replace('size="0.005" mass', 'size="0.0005" mass').replace(
        'pos="0 0 0.005"', 'pos="0 0 0.0005"'
    )
    default = mujoco.MjModel.from_xml_string(with_config(small, **COARSE, friction="0"))
    relax = mujoco.MjModel.from_xml_string(
        with_config(small, **COARSE, friction="0", solver="relaxation")
    )
    d_default, d_relax = mujoco.MjData(default), mujoco.MjData(relax)
    for d in (0.2e-3, 0.3e-3):
        force = evaluate(default, d_default, d)["force"]
        f_ref = hertz_bonded(1.19e5, 0.43, 0.0005, d, 0.004)
        assert abs(force[2] / f_ref - 1) < 0.25, (d, force[2], f_ref)
        assert evaluate(relax, d_relax, d)["force"][2] == 0.0
