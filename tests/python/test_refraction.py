"""The `camera` and `index` attributes through the real plugin: a pinhole camera under the
refracting gel sees the same image as the orthographic one without contact, and a sphere
press deeper off the axis (parallax), less so through a denser gel; bad values are refused
at load."""

import mujoco
import numpy as np
import pytest

from conftest import evaluate, with_config

W, H = 96, 72  # 0.25 mm pixels over the default 24 x 18 mm field of view


def images(press_xml, depth_m, **camera):
    """Depth and contact images of the example's sphere (R = 5 mm, on the gel's axis)
    pressed ``depth_m``, rigid physics, through ``camera`` (attributes)."""
    xml = with_config(
        press_xml, physics="rigid", outputs="depth contact", resolution=f"{W} {H}", **camera
    )
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    out = evaluate(model, data, depth_m)
    return out["depth"], out["contact"]


def test_pinhole_sees_the_press_deeper_off_axis_and_the_flat_gel_alike(press_xml):
    pinhole = {"camera": "pinhole 0.01", "index": "1.4"}
    # No contact: every camera shows the same (flat) image.
    for a, b in zip(images(press_xml, -1e-3), images(press_xml, -1e-3, **pinhole)):
        assert np.array_equal(a, b)

    press = 1e-3  # contact radius 3 mm
    ortho, ortho_mask = images(press_xml, press)
    # Orthographic with an index: the default image, bit for bit.
    same, same_mask = images(press_xml, press, camera="orthographic", index="1.4")
    assert np.array_equal(same, ortho) and np.array_equal(same_mask, ortho_mask)

    dense, dense_mask = images(press_xml, press, **pinhole)
    plain, _ = images(press_xml, press, camera="pinhole 0.01", index="1")
    assert np.all(np.isfinite(dense)) and dense.max() <= press + 1e-12
    # The cap's rim lies on the top face, where every ray starts: the contact is seen at
    # the same pixels.
    assert np.array_equal(dense_mask, ortho_mask)
    assert np.array_equal(dense > 0, ortho > 0)
    # Off the axis each ray slants towards it as it goes down, so it meets the cap nearer
    # its centre, where it is deeper: the pinhole's depth is never less, and more by tens
    # of micrometres near the rim (28 um here, 37 um with index 1). A denser gel bends the
    # rays towards the vertical: less parallax. (Tolerance 1e-12 m, rounding: all three
    # images come from the same orthographic surface.)
    assert np.all(dense >= ortho - 1e-12)
    assert np.all(plain >= dense - 1e-12)
    gain = (dense - ortho).max()
    assert 1e-5 < gain < (plain - ortho).max() - 5e-6, gain
    # Near the axis the rays are vertical: the centre's depth hardly changes.
    rc, cc = H // 2, W // 2
    assert abs(dense[rc, cc] - ortho[rc, cc]) < 1e-7


@pytest.mark.parametrize(
    "key, value",
    [("camera", "pinhole"), ("camera", "pinhole 0"), ("camera", "pinhole 15"), ("index", "0.8")],
)
def test_bad_camera_values_are_refused(press_xml, key, value):
    xml = with_config(press_xml, physics="rigid", resolution="40 30", **{key: value})
    with pytest.raises(ValueError) as err:
        mujoco.MjModel.from_xml_string(xml)
    msg = str(err.value)
    assert f"'{key}'" in msg and "'touch'" in msg and value in msg, msg
