"""The coarse MPM gel through the real `mujoco` Python package: physics sanity, state
handling per MjData, determinism across solver threads and Python threads."""

import mujoco
import numpy as np

import tacrom
from conftest import evaluate, in_threads, with_config

COARSE = dict(physics="coarse", outputs="depth force contact", resolution="64 48")


def test_coarse_press_physics(press_xml):
    model = mujoco.MjModel.from_xml_string(with_config(press_xml, **COARSE))
    data = mujoco.MjData(model)
    forces = []
    for d in (0.1e-3, 0.3e-3, 0.5e-3):
        out = evaluate(model, data, d)
        depth, force, contact = out["depth"], out["force"], out["contact"]
        assert depth.shape == (48, 64) and contact.shape == (48, 64) and force.shape == (3,)
        assert np.all(np.isfinite(depth)) and depth.min() >= 0.0 and depth.max() <= 0.004
        # Where the sphere touches, the surface follows it: the peak is the press depth.
        assert abs(depth.max() - d) < 0.05e-3
        # The gel sags beyond the contact patch (a rigid model would not).
        assert np.count_nonzero((contact == 0) & (depth > 1e-6)) > 0
        # Centred press: the image is mirror symmetric to solver tolerance (5 % of peak).
        assert np.abs(depth - depth[:, ::-1]).max() < 0.05 * d
        assert np.abs(depth - depth[::-1, :]).max() < 0.05 * d
        forces.append(force[2])
    assert 0 < forces[0] < forces[1] < forces[2]


def test_reset_and_copy_with_gel_state(press_xml):
    model = mujoco.MjModel.from_xml_string(with_config(press_xml, **COARSE))
    data = mujoco.MjData(model)
    before = evaluate(model, data, 0.4e-3)["depth"]
    clone = mujoco.MjData(model)
    mujoco.mj_copyData(clone, model, data)
    np.testing.assert_array_equal(tacrom.depth(model, clone, "touch"), before)
    # The copy carries the gel: evaluating it again at the same pose reproduces the image.
    mujoco.mj_forward(model, clone)
    np.testing.assert_allclose(tacrom.depth(model, clone, "touch"), before, atol=2e-6)
    mujoco.mj_resetData(model, data)
    assert np.all(tacrom.depth(model, data, "touch") == 0.0)


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
    gives a bounded image whose peak is the press depth."""
    xml = with_config(press_xml, outputs="depth contact", resolution="64 48")  # physics: default
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    for d in (0.2e-3, 0.5e-3):
        out = evaluate(model, data, d)
        depth = out["depth"]
        assert np.all(np.isfinite(depth)) and depth.min() >= 0.0 and depth.max() <= 0.004
        assert abs(depth.max() - d) < 0.05e-3
        # Where the sphere touches, the image is at least its penetration.
        assert np.all(depth[out["contact"] == 1] > 0.0)


def test_rom_bad_model_directory_names_the_attribute(press_xml, tmp_path):
    import pytest

    xml = with_config(press_xml, physics="rom", model=str(tmp_path / "nowhere"))
    with pytest.raises(ValueError) as err:
        mujoco.MjModel.from_xml_string(xml)
    assert "'model'" in str(err.value) and "'touch'" in str(err.value)
