"""The `pressure` output through the real plugin: it integrates to the normal force, is
zero without contact, and needs a gel."""

import mujoco
import numpy as np
import pytest

import tacrom
from conftest import evaluate, with_config

W, H = 96, 72  # 0.25 mm pixels over the default 24 x 18 mm field of view


@pytest.mark.parametrize("physics", ["coarse", "rom"])
def test_pressure_integrates_to_the_normal_force(press_xml, physics):
    xml = with_config(
        press_xml, physics=physics, outputs="force pressure", resolution=f"{W} {H}"
    )
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    lay = tacrom.layout(model, "touch")
    assert lay["outputs"]["pressure"]["shape"] == (H, W)
    pixel = (24e-3 / W) * (18e-3 / H)

    evaluate(model, data, -1e-3)
    assert np.all(tacrom.pressure(model, data, "touch") == 0.0)

    for press in (0.3e-3, 0.6e-3):
        out = evaluate(model, data, press)
        p, fz = out["pressure"], out["force"][2]
        assert p.shape == (H, W) and np.all(np.isfinite(p))
        assert fz > 0.0
        # The image holds the same contact loads that the force sums (the contact, a few
        # mm across, lies inside the 24 x 18 mm image): equal up to round-off.
        assert p.sum() * pixel == pytest.approx(fz, rel=1e-6)
        # Compressive, and largest near the centre the sphere presses.
        assert p.min() >= -1e-9 * p.max()
        r, c = np.unravel_index(np.argmax(p), p.shape)
        assert abs(r - H / 2) * 0.25 < 2.0 and abs(c - W / 2) * 0.25 < 2.0, (r, c)

    evaluate(model, data, -1e-3)
    assert np.all(tacrom.pressure(model, data, "touch") == 0.0)


def test_rigid_physics_refuses_pressure(press_xml):
    xml = with_config(press_xml, physics="rigid", outputs="depth pressure", resolution="40 30")
    with pytest.raises(ValueError) as err:
        mujoco.MjModel.from_xml_string(xml)
    msg = str(err.value)
    assert "pressure" in msg and "'touch'" in msg
