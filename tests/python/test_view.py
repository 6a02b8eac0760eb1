"""The sensor in MuJoCo's viewer: the plugin's ``visualize`` callback, checked through the
scene MuJoCo builds (``mjv_updateScene`` calls plugin callbacks and needs no OpenGL), and
the parts of ``python -m tacrom.view`` that need no display.

The callback draws, when the scene shows contact points or contact forces, the deformed gel
as at most 399 thin boxes posed in the sensor's site frame, and with contact forces the
total force as an arrow; nothing otherwise, and nothing without contact."""

import os
import subprocess
import sys
import textwrap
import time

import mujoco
import numpy as np
import pytest

import tacrom
from tacrom import view
from conftest import ROOT, evaluate, with_config

W, H = 64, 48
FOV = (0.024, 0.018)
T = 0.004
BUDGET = 400  # tacrom::visual::GEOM_BUDGET
TILE = (FOV[0] / 23, FOV[1] / 17)  # the tile grid for 399 tiles over a 4:3 field of view
PRESS_AT = (0.004, 0.002)  # indenter position in the site frame (posed scene)

CP = mujoco.mjtVisFlag.mjVIS_CONTACTPOINT
CF = mujoco.mjtVisFlag.mjVIS_CONTACTFORCE


def posed(xml: str) -> str:
    """The press scene with the sensor moved and turned (so that frame mistakes show) and
    the indenter, nested in the sensor body, off the gel's centre at ``PRESS_AT``."""
    sensor_open = '<body name="sensor" pos="0 0 0">'
    indenter_open = '<body name="indenter" pos="0 0 0.005">'
    assert sensor_open in xml and indenter_open in xml, "examples/press.xml changed"
    xml = xml.replace(sensor_open, '<body name="sensor" pos="0.05 -0.02 0.1" euler="20 -10 90">')
    i = xml.index(indenter_open)
    close = xml.rindex("</body>", 0, i)
    xml = xml[:close] + xml[close + len("</body>") :]
    i = xml.index(indenter_open)
    end = xml.index("</body>", i) + len("</body>")
    xml = xml[:end] + "\n    </body>" + xml[end:]
    x, y = PRESS_AT
    return xml.replace(indenter_open, f'<body name="indenter" pos="{x} {y} 0.005">')


def coarse(xml: str) -> str:
    return with_config(xml, physics="coarse", outputs="depth force", resolution=f"{W} {H}")


def options(point: bool, force: bool) -> mujoco.MjvOption:
    opt = mujoco.MjvOption()
    opt.flags[CP] = int(point)
    opt.flags[CF] = int(force)
    return opt


def update_scene(model, data, opt, maxgeom=4000) -> mujoco.MjvScene:
    scn = mujoco.MjvScene(model, maxgeom)
    mujoco.mjv_updateScene(
        model, data, opt, mujoco.MjvPerturb(), mujoco.MjvCamera(), mujoco.mjtCatBit.mjCAT_ALL, scn
    )
    return scn


def own_geoms(model, data, opt) -> list:
    """What MuJoCo itself adds to a scene: ``mjv_addGeoms`` alone calls no plugin."""
    scn = mujoco.MjvScene(model, 4000)
    mujoco.mjv_addGeoms(model, data, opt, mujoco.MjvPerturb(), mujoco.mjtCatBit.mjCAT_ALL, scn)
    return [signature(scn.geoms[i]) for i in range(scn.ngeom)]


def signature(g):
    return (g.type, g.objtype, g.objid, g.category, tuple(np.round(g.pos, 9)))


def tacrom_geoms(scn, model, sensor="touch") -> list:
    sid = model.sensor(sensor).id
    return [
        scn.geoms[i]
        for i in range(scn.ngeom)
        if scn.geoms[i].objtype == mujoco.mjtObj.mjOBJ_SENSOR and scn.geoms[i].objid == sid
    ]


def site_frame(model, data, sensor="touch"):
    site = model.sensor_objid[model.sensor(sensor).id]
    return data.site_xpos[site].copy(), data.site_xmat[site].reshape(3, 3).copy()


def local(frame, pos):
    p, r = frame
    return r.T @ (np.asarray(pos) - p)


@pytest.fixture
def posed_model(press_xml):
    return mujoco.MjModel.from_xml_string(coarse(posed(press_xml)))


@pytest.mark.parametrize("point, force", [(True, False), (False, True), (True, True)])
def test_contact_flags_draw_the_gel_under_the_site_deepest_at_the_press(posed_model, point, force):
    model = posed_model
    data = mujoco.MjData(model)
    out = evaluate(model, data, 0.6e-3)
    depth, f = out["depth"], out["force"]
    assert depth.max() > 0.4e-3 and f[2] > 0.05, (depth.max(), f)

    opt = options(point, force)
    scn = update_scene(model, data, opt)
    own = own_geoms(model, data, opt)
    ours = tacrom_geoms(scn, model)
    assert 1 < len(ours) <= BUDGET
    # The plugin's geoms come first (MuJoCo calls plugins before adding its own); the rest
    # is exactly what MuJoCo draws by itself.
    assert scn.ngeom == len(own) + len(ours)
    assert [signature(scn.geoms[i]) for i in range(len(ours), scn.ngeom)] == own
    assert all(g.category == mujoco.mjtCatBit.mjCAT_DECOR for g in ours)

    frame = site_frame(model, data)
    tiles = [g for g in ours if g.type == mujoco.mjtGeom.mjGEOM_BOX]
    arrows = [g for g in ours if g.type == mujoco.mjtGeom.mjGEOM_ARROW]
    assert len(tiles) == 23 * 17
    assert len(arrows) == (1 if force else 0)

    # Under the site, within the field of view on the gel, inside the gel's thickness.
    pts = np.array([local(frame, g.pos) for g in tiles])
    assert np.all(np.abs(pts[:, 0]) <= FOV[0] / 2) and np.all(np.abs(pts[:, 1]) <= FOV[1] / 2)
    assert np.all(pts[:, 2] <= 0.0) and np.all(pts[:, 2] >= -T)
    # Flat gel far from the press: level with the top face, facing the site's +z.
    corner = tiles[int(np.argmin(np.hypot(pts[:, 0] + 0.012, pts[:, 1] - 0.009)))]
    assert abs(local(frame, corner.pos)[2]) < 0.1e-3
    normal = corner.mat.reshape(3, 3)[:, 2]
    assert np.allclose(normal, frame[1][:, 2], atol=1e-5)

    # The deepest tile is where the press is deepest, as deep as the image.
    k = int(np.argmin(pts[:, 2]))
    assert abs(pts[k, 0] - PRESS_AT[0]) <= TILE[0], pts[k]
    assert abs(pts[k, 1] - PRESS_AT[1]) <= TILE[1], pts[k]
    r, c = np.unravel_index(np.argmax(depth), depth.shape)
    px, py = -FOV[0] / 2 + (c + 0.5) * FOV[0] / W, FOV[1] / 2 - (r + 0.5) * FOV[1] / H
    assert abs(pts[k, 0] - px) <= TILE[0] and abs(pts[k, 1] - py) <= TILE[1]
    assert depth.max() <= -pts[k, 2] <= depth.max() + 0.2e-3
    # Coloured by depth: the deepest red, the flat gel grey.
    assert tiles[k].rgba[0] > 0.8 and tiles[k].rgba[2] < 0.3, tiles[k].rgba
    assert np.allclose(corner.rgba[:3], [0.72, 0.74, 0.78], atol=1e-6)

    if force:
        (arrow,) = arrows
        direction = arrow.mat.reshape(3, 3)[:, 2]
        want = frame[1] @ f
        assert np.dot(direction, want / np.linalg.norm(want)) > 1 - 1e-5
        length = np.linalg.norm(f) * model.vis.map.force / model.stat.meanmass
        assert arrow.size[2] == pytest.approx(length, rel=1e-5)
        width = model.vis.scale.forcewidth * model.stat.meansize
        assert arrow.size[0] == pytest.approx(width, rel=1e-5)
        assert np.allclose(arrow.rgba, model.vis.rgba.contactforce)
        tail = local(frame, arrow.pos)
        assert np.hypot(tail[0] - PRESS_AT[0], tail[1] - PRESS_AT[1]) < 0.5e-3, tail
        assert -depth.max() <= tail[2] <= 0.0


def test_flags_off_draw_exactly_mujocos_geoms(posed_model):
    model = posed_model
    data = mujoco.MjData(model)
    evaluate(model, data, 0.6e-3)
    off = options(False, False)
    scn = update_scene(model, data, off)
    assert tacrom_geoms(scn, model) == []
    assert [signature(scn.geoms[i]) for i in range(scn.ngeom)] == own_geoms(model, data, off)
    # The same state with the flags on gains the sensor's geoms.
    assert update_scene(model, data, options(True, True)).ngeom > scn.ngeom


def test_no_contact_draws_nothing(posed_model):
    model = posed_model
    data = mujoco.MjData(model)
    evaluate(model, data, -1e-3)  # the sphere 1 mm above the gel
    assert tacrom.depth(model, data, "touch").max() == 0.0
    on = options(True, True)
    scn = update_scene(model, data, on)
    assert tacrom_geoms(scn, model) == []
    assert [signature(scn.geoms[i]) for i in range(scn.ngeom)] == own_geoms(model, data, on)
    # After a press, resetting the data clears the drawing too.
    evaluate(model, data, 0.5e-3)
    assert tacrom_geoms(update_scene(model, data, on), model)
    mujoco.mj_resetData(model, data)
    assert tacrom_geoms(update_scene(model, data, on), model) == []


def test_a_rigid_sensor_draws_the_surface_and_no_arrow(press_xml):
    # The stock example: rigid physics, depth only, so there is no force to draw.
    xml = with_config(press_xml, physics="rigid", resolution="320 240")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    evaluate(model, data, 0.5e-3)
    ours = tacrom_geoms(update_scene(model, data, options(True, True)), model)
    assert len(ours) == 23 * 17
    assert all(g.type == mujoco.mjtGeom.mjGEOM_BOX for g in ours)


def test_a_small_scene_is_filled_never_overrun(posed_model):
    model = posed_model
    data = mujoco.MjData(model)
    evaluate(model, data, 0.6e-3)
    for maxgeom in (1, 10, 50):
        scn = update_scene(model, data, options(True, True), maxgeom=maxgeom)
        assert scn.ngeom == maxgeom
        assert len(tacrom_geoms(scn, model)) == maxgeom


def test_a_copy_of_the_data_draws_the_same(posed_model):
    # The passive viewer draws its own copy of the user's data (mjv_copyData, which runs
    # the plugin's copy callback).
    model = posed_model
    data = mujoco.MjData(model)
    evaluate(model, data, 0.6e-3)
    copy = mujoco.MjData(model)
    mujoco.mj_copyData(copy, model, data)
    on = options(True, True)
    a, b = update_scene(model, data, on), update_scene(model, copy, on)
    assert a.ngeom == b.ngeom > 0
    assert [signature(a.geoms[i]) for i in range(a.ngeom)] == [
        signature(b.geoms[i]) for i in range(b.ngeom)
    ]


def test_callback_cost(press_xml, capsys):
    """One mjv_updateScene with the flags off and on (320 x 240 depth image; reported, and
    bounded loosely against a stall)."""
    xml = with_config(press_xml, physics="rigid", resolution="320 240")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    evaluate(model, data, 0.8e-3)
    scn = mujoco.MjvScene(model, 4000)
    pert, cam = mujoco.MjvPerturb(), mujoco.MjvCamera()
    median = {}
    for name, opt in (("off", options(False, False)), ("on", options(True, True))):
        times = []
        for _ in range(200):
            t0 = time.perf_counter()
            mujoco.mjv_updateScene(model, data, opt, pert, cam, mujoco.mjtCatBit.mjCAT_ALL, scn)
            times.append(time.perf_counter() - t0)
        median[name] = float(np.median(times))
    with capsys.disabled():
        print(
            "\nmjv_updateScene, press example (320 x 240): "
            f"flags off {median['off'] * 1e6:.1f} us, "
            f"on {median['on'] * 1e6:.1f} us ({scn.ngeom} geoms)"
        )
    assert median["on"] < 0.05


RENDER = textwrap.dedent(
    """
    import sys
    import mujoco, numpy as np
    import tacrom
    model = mujoco.MjModel.from_xml_string(open(sys.argv[1]).read())
    data = mujoco.MjData(model)
    data.qpos[0] = 0.6e-3
    mujoco.mj_forward(model, data)
    try:
        renderer = mujoco.Renderer(model, 240, 320)
    except Exception as e:
        print("NO-GL", e)
        sys.exit(0)
    cam = mujoco.MjvCamera()
    cam.lookat[:] = data.site_xpos[0]
    cam.distance, cam.elevation, cam.azimuth = 0.06, -60.0, 90.0
    images = []
    for on in (0, 1):
        opt = mujoco.MjvOption()
        opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTPOINT] = on
        renderer.update_scene(data, camera=cam, scene_option=opt)
        images.append(renderer.render().astype(float))
    np.save(sys.argv[2], np.stack(images))
    print("OK")
    """
)


def test_offscreen_render_shows_the_gel(press_xml, tmp_path):
    """Through a real renderer (EGL, in a child process: MUJOCO_GL is read at import); skipped
    where no offscreen OpenGL is available."""
    scene = tmp_path / "scene.xml"
    scene.write_text(with_config(press_xml, physics="rigid", resolution=f"{W} {H}"))
    out = tmp_path / "images.npy"
    env = dict(os.environ, MUJOCO_GL="egl")
    res = subprocess.run(
        [sys.executable, "-c", RENDER, str(scene), str(out)],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    if res.returncode != 0 or "NO-GL" in res.stdout:
        pytest.skip(f"no offscreen OpenGL (MUJOCO_GL=egl): {res.stdout[-300:]} {res.stderr[-300:]}")
    off, on = np.load(out)
    changed = np.any(np.abs(on - off) > 8, axis=2)
    assert changed.mean() > 0.05, changed.mean()
    # The gel's flat tiles are light grey; without them the background is dark.
    grey = np.all((on > 120) & (on < 230), axis=2) & (np.ptp(on, axis=2) < 40)
    assert (grey & changed).mean() > 0.03


# --- python -m tacrom.view, without a display ----------------------------------------------


def test_view_lists_and_checks_sensors(press_xml):
    model = mujoco.MjModel.from_xml_string(press_xml)
    assert view.tacrom_sensors(model) == ["touch"]
    assert view.tacrom_sensors(model, "touch") == ["touch"]
    with pytest.raises(view.ViewError, match="no tacrom sensor named 'nope'.*touch"):
        view.tacrom_sensors(model, "nope")
    bare = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><site name='s'/></worldbody></mujoco>"
    )
    with pytest.raises(view.ViewError, match="no tacrom.tactile sensor"):
        view.tacrom_sensors(bare)


def test_view_ignores_other_plugins_sensors(press_xml):
    # A sensor of MuJoCo's own touch_grid plugin beside the tacrom one is not listed.
    mujoco._load_all_bundled_plugins()
    xml = press_xml.replace(
        "<extension>", '<extension><plugin plugin="mujoco.sensor.touch_grid"/>'
    ).replace(
        "</sensor>",
        '<plugin name="grid" plugin="mujoco.sensor.touch_grid" objtype="site" objname="gel">'
        '<config key="size" value="4 4"/><config key="fov" value="30 30"/>'
        '<config key="gamma" value="0"/><config key="nchannel" value="1"/></plugin></sensor>',
    )
    try:
        model = mujoco.MjModel.from_xml_string(xml)
    except ValueError as e:
        pytest.skip(f"touch_grid plugin unavailable: {e}")
    assert view.tacrom_sensors(model) == ["touch"]
    with pytest.raises(ValueError, match="touch_grid"):
        tacrom.layout(model, "grid")


def test_view_images_of_a_sensor(press_xml):
    xml = with_config(press_xml, physics="rigid", outputs="depth rgb", resolution=f"{W} {H}")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    evaluate(model, data, 0.5e-3)
    images = dict(view.sensor_images(model, data, "touch"))
    assert list(images) == ["touch depth", "touch rgb"]
    for img in images.values():
        assert img.shape == (H, W, 3) and img.dtype == np.uint8
    depth = tacrom.depth(model, data, "touch")
    d = images["touch depth"]
    # Grey where flat, red at the deepest point (the scene's tile colours).
    assert tuple(d[0, 0]) == tuple(view.DEPTH_COLOURS[0].astype(np.uint8))
    r, c = np.unravel_index(np.argmax(depth), depth.shape)
    assert tuple(d[r, c]) == tuple(view.DEPTH_COLOURS[-1].astype(np.uint8))
    rgb = np.clip(tacrom.rgb(model, data, "touch") + 0.5, 0, 255).astype(np.uint8)
    assert np.array_equal(images["touch rgb"], rgb)
    assert "depth 0." in view.sensor_summary(model, data, "touch")


def test_view_panels_fit_in_the_viewport():
    viewport = (100, 50, 800, 600)
    rects = view.layout_panels(viewport, [(240, 320), (240, 320)])
    assert all(r is not None for r in rects)
    for x, y, w, h in rects:
        assert 100 <= x and x + w <= 900 and 50 <= y and y + h <= 650
        assert w / h == pytest.approx(320 / 240, rel=0.02)
    (x0, y0, _, _), (x1, y1, _, h1) = rects
    assert y1 + h1 <= y0  # stacked top down, no overlap
    # No room: nothing placed.
    assert view.layout_panels((0, 0, 40, 30), [(240, 320)]) == [None]
    img = np.arange(12, dtype=np.uint8).reshape(2, 2, 3)
    assert view.resize(img, 4, 4).shape == (4, 4, 3)


def test_view_turns_on_the_contact_flags():
    opt = mujoco.MjvOption()
    assert not opt.flags[CP] and not opt.flags[CF]
    view.show_contacts(opt)
    assert opt.flags[CP] and opt.flags[CF]


def test_view_arguments():
    args = view.parse_args(["scene.xml", "--seconds", "2.5", "--sensor", "touch"])
    assert (str(args.scene), args.seconds, args.sensor) == ("scene.xml", 2.5, "touch")
    assert view.parse_args(["scene.xml"]).seconds is None
    with pytest.raises(SystemExit):
        view.parse_args(["scene.xml", "--seconds", "0"])


def test_view_without_a_display_fails_clearly(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if sys.platform.startswith("linux"):
        with pytest.raises(view.ViewError, match="no display"):
            view.require_display()
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    press = ROOT / "examples" / "press.xml"
    res = subprocess.run(
        [sys.executable, "-m", "tacrom.view", str(press), "--seconds", "1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert "tacrom.view: no display" in res.stderr
    res = subprocess.run(
        [sys.executable, "-m", "tacrom.view", str(press), "--sensor", "x"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2 and "no tacrom sensor named 'x'" in res.stderr
