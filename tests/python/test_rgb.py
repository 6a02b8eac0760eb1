"""The `rgb` output through the real plugin: shape and scale, the flat gel's uniform
background, and a press seen the way a GelSight camera sees it (each light's colour on the
side of the dent nearer that light)."""

import mujoco
import numpy as np
import pytest

import tacrom
from conftest import evaluate, with_config

W, H = 64, 48  # 0.375 mm pixels over the default 24 x 18 mm field of view


@pytest.mark.parametrize("physics", ["rigid", "coarse"])
def test_rgb_shows_a_press_and_the_background_without_contact(press_xml, physics):
    xml = with_config(press_xml, physics=physics, outputs="depth rgb", resolution=f"{W} {H}")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    lay = tacrom.layout(model, "touch")
    assert lay["outputs"]["rgb"] == {"offset": W * H, "shape": (H, W, 3), "unit": "0..255"}

    # No contact (the sphere 1 mm above the gel): one uniform, mid-grey background.
    out = evaluate(model, data, -1e-3)
    flat = tacrom.rgb(model, data, "touch")
    assert flat.shape == (H, W, 3)
    background = flat[0, 0]
    assert np.all(flat == background)
    assert np.all((background > 50) & (background < 200)), background

    previous_change = 0.0
    for press in (0.3e-3, 0.6e-3):
        out = evaluate(model, data, press)
        img, depth = out["rgb"], out["depth"]
        assert img.shape == (H, W, 3)
        assert np.all(np.isfinite(img)) and img.min() >= 0.0 and img.max() <= 255.0
        # Where the surface is flat (the pixel and its four neighbours undeformed), the
        # image is exactly the background; the dent changes it.
        padded = np.pad(depth, 1, mode="edge")
        undeformed = (
            (padded[1:-1, 1:-1] == 0)
            & (padded[:-2, 1:-1] == 0)
            & (padded[2:, 1:-1] == 0)
            & (padded[1:-1, :-2] == 0)
            & (padded[1:-1, 2:] == 0)
        )
        assert undeformed.sum() > 0.5 * W * H
        assert np.all(img[undeformed] == background)
        change = np.abs(img - background).max()
        assert change > 20.0, change  # tens of grey levels: a visible dent
        assert change > previous_change  # steeper slopes, stronger colours
        previous_change = change
        # The built-in lights: red at +y (the image's top), green at 210 degrees (lower
        # left), blue at 330 degrees (lower right). Each lights the side of the dent
        # nearer to it, which faces it, and leaves the far side darker. The sphere presses
        # the centre (contact radius 1.7 mm at 0.3 mm); sample 1.3 mm from it.
        rc, cc = H // 2, W // 2  # the pixel 0.19 mm right of and below the centre
        up, down = img[rc - 4, cc], img[rc + 3, cc]
        left, right = img[rc, cc - 4], img[rc, cc + 3]
        assert up[0] > background[0] > down[0], (up, down)
        assert left[1] > background[1] > right[1], (left, right)
        assert right[2] > background[2] > left[2], (left, right)

    # Released: the gel relaxes flat and shows the background again.
    evaluate(model, data, -1e-3)
    np.testing.assert_array_equal(tacrom.rgb(model, data, "touch"), flat)


def test_save_png_writes_colour(tmp_path):
    import struct
    import zlib

    img = np.zeros((2, 3, 3))
    img[0, 0] = (255, 0, 0)
    img[1, 2] = (0, 128, 255)
    path = tmp_path / "rgb.png"
    tacrom.save_png(path, img)
    data = path.read_bytes()
    width, height, depth, colour_type = struct.unpack(">IIBB", data[16:26])
    assert (width, height, depth, colour_type) == (3, 2, 8, 2)
    idat = data.index(b"IDAT")
    (length,) = struct.unpack(">I", data[idat - 4 : idat])
    raw = zlib.decompress(data[idat + 4 : idat + 4 + length])
    rows = [raw[r * 10 + 1 : (r + 1) * 10] for r in range(2)]  # filter byte + 3 x RGB
    assert rows[0][:3] == bytes((255, 0, 0)) and rows[1][6:] == bytes((0, 128, 255))


def test_markers_are_drawn_into_rgb(press_xml):
    """With the markers output, each marker is a dark dot in the rgb image where the
    markers output says the camera sees it; everywhere else the image is the one without
    markers."""
    images = {}
    for outputs in ("depth rgb", "depth rgb markers"):
        xml = with_config(press_xml, physics="coarse", outputs=outputs, resolution=f"{W} {H}")
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        out = evaluate(model, data, 0.4e-3)
        images[outputs] = out
    plain, dotted = images["depth rgb"]["rgb"], images["depth rgb markers"]["rgb"]
    markers = images["depth rgb markers"]["markers"]
    changed = np.any(plain != dotted, axis=2)
    near = np.zeros_like(changed)
    for col, row, _, _ in markers:
        # The dot (0.25 mm, 0.67 px) reaches the pixels around its centre and no farther.
        r0, c0 = int(np.floor(row)), int(np.floor(col))
        near[max(r0 - 1, 0) : r0 + 3, max(c0 - 1, 0) : c0 + 3] = True
        darkest = dotted[max(r0, 0) : r0 + 2, max(c0, 0) : c0 + 2].sum(axis=2).min()
        lit = plain[max(r0, 0) : r0 + 2, max(c0, 0) : c0 + 2].sum(axis=2).min()
        assert darkest < lit - 50.0, (col, row, darkest, lit)
    assert not np.any(changed & ~near)
