"""Calibrated optics (`tacrom calibrate`, the `optics` attribute) through MuJoCo.

Ball presses are drawn here, in numpy, with an optical response unlike the built-in one (a
linear colour change per surface slope over a ramp background) and calibrated with the
`tacrom` command; a sensor loading the file shows that background, resampled, where the gel
is flat and that response where it is pressed, unlike the built-in optics. A bad file fails
the load naming the sensor and the attribute."""

import json
import subprocess

import mujoco
import numpy as np
import pytest

import tacrom
from conftest import ROOT, evaluate, with_config

TOOL = ROOT / "target" / "release" / "tacrom"
CAL_W, CAL_H, CAL_PIXEL = 160, 120, 0.15e-3  # calibration images: 24 x 18 mm
W, H, PIXEL = 64, 48, 0.375e-3  # the sensor: the default 24 x 18 mm field of view


def response(gx, gy):
    """Colour change (grey levels) per depth gradient: red grows towards +x slopes, green
    towards +y, blue with their difference."""
    return np.stack([120.0 * gx, 120.0 * gy, 60.0 * (gx - gy)], axis=-1)


def ramp_background(w, h, scale=1.0):
    """Red rises by one level per calibration pixel along the columns, green along the
    rows; ``scale`` is calibration pixels per image pixel, ``(c + 1/2) scale - 1/2`` the
    calibration coordinate of column ``c`` (pixel centres aligned)."""
    u = (np.arange(w) + 0.5) * scale - 0.5
    v = (np.arange(h) + 0.5) * scale - 0.5
    bg = np.empty((h, w, 3))
    bg[..., 0] = 60.0 + u[None, :]
    bg[..., 1] = 80.0 + v[:, None]
    bg[..., 2] = 128.0
    return bg


@pytest.fixture(scope="module")
def optics_file(tmp_path_factory):
    assert TOOL.is_file(), f"{TOOL} is missing: run `make build` first"
    folder = tmp_path_factory.mktemp("calibration")
    bg = ramp_background(CAL_W, CAL_H)
    tacrom.save_png(folder / "background.png", bg)
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:CAL_H, 0:CAL_W]
    presses = []
    for i in range(12):
        radius = rng.uniform(3e-3, 5e-3)
        a = rng.uniform(0.3, 0.6) * radius / CAL_PIXEL  # contact radius, pixels
        cx = rng.uniform(a + 3, CAL_W - 4 - a)
        cy = rng.uniform(a + 3, CAL_H - 4 - a)
        # The sphere cap's gradient, x towards the columns, y towards the top row.
        x, y = (cols - cx) * CAL_PIXEL, (cy - rows) * CAL_PIXEL
        inside = np.hypot(x, y) <= a * CAL_PIXEL
        root = np.sqrt(np.maximum(radius**2 - x**2 - y**2, 1e-30))
        gx, gy = np.where(inside, -x / root, 0.0), np.where(inside, -y / root, 0.0)
        name = f"press_{i:02d}.png"
        tacrom.save_png(folder / name, bg + response(gx, gy))
        presses.append(
            {
                "image": name,
                "ball_radius_mm": radius * 1e3,
                "pixel_size_mm": CAL_PIXEL * 1e3,
                "center_px": [cx, cy],
                "contact_radius_px": a,
            }
        )
    (folder / "presses.json").write_text(json.dumps({"presses": presses}))
    out = folder / "optics.json"
    run = subprocess.run(
        [str(TOOL), "calibrate", str(folder), "--out", str(out)], capture_output=True, text=True
    )
    assert run.returncode == 0, run.stderr
    assert "held out" in run.stdout
    return out


def sensor(press_xml, **config):
    xml = with_config(press_xml, physics="rigid", outputs="depth rgb", resolution=f"{W} {H}", **config)
    model = mujoco.MjModel.from_xml_string(xml)
    return model, mujoco.MjData(model)


def test_calibrated_optics_show_their_background_and_response(press_xml, optics_file):
    model, data = sensor(press_xml, optics=str(optics_file))
    built_in = sensor(press_xml)

    # No contact: the calibration's ramp resampled to 64 x 48 (2.5 calibration pixels per
    # pixel). Bilinear resampling of a linear ramp is exact, and every sample point lies
    # between calibration pixel centres (0.75 to 159.25), so no clamping.
    flat = evaluate(model, data, -1e-3)["rgb"]
    np.testing.assert_allclose(flat, ramp_background(W, H, CAL_W / W), rtol=0, atol=1e-9)

    # A 0.5 mm press of the 5 mm sphere: the colour is the background plus the calibrated
    # response at the sensor's own depth gradient (central differences, one-sided at the
    # border, as the renderer takes them).
    out = evaluate(model, data, 0.5e-3)
    rgb, depth = out["rgb"], out["depth"]
    gx = np.gradient(depth, PIXEL, axis=1)
    gy = -np.gradient(depth, PIXEL, axis=0)  # row 0 is +y
    g_max = json.loads(optics_file.read_text())["range"][0]
    sloped = (gx != 0) | (gy != 0)
    inside = sloped & (np.abs(gx) < 0.9 * g_max) & (np.abs(gy) < 0.9 * g_max)
    assert inside.sum() > 100, inside.sum()  # the contact: 2.2 mm, 6 pixels in radius
    expected = np.clip(flat + response(gx, gy), 0, 255)
    err = np.abs(rgb - expected)[inside]
    # The table fitted to 8-bit images of a linear response: the fit is exact for a linear
    # response (no curvature to penalise), so what remains is the images' rounding (+-0.5)
    # averaged over the samples of each node (measured: mean 0.08, worst 0.33 levels over
    # the 148 sloped pixels).
    assert err.mean() < 0.25 and err.max() < 1.5, (err.mean(), err.max())
    # Unsloped pixels show the background.
    np.testing.assert_array_equal(rgb[~sloped], flat[~sloped])

    # The built-in optics see the same press differently.
    other = evaluate(*built_in, 0.5e-3)["rgb"]
    np.testing.assert_array_equal(evaluate(*built_in, 0.5e-3)["depth"], depth)
    assert np.abs(other - rgb)[sloped].mean() > 10.0
    assert np.abs(other - rgb)[~sloped].mean() > 10.0  # another background


def test_a_missing_optics_file_fails_the_load(press_xml, tmp_path):
    path = str(tmp_path / "no_such_optics.json")
    with pytest.raises(ValueError) as err:
        sensor(press_xml, optics=path)
    msg = str(err.value)
    assert "'touch'" in msg and "'optics'" in msg and path in msg and "cannot read" in msg
    # Without the rgb output the file is not read.
    xml = with_config(press_xml, physics="rigid", outputs="depth", optics=path)
    mujoco.MjModel.from_xml_string(xml)
