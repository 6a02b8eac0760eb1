"""Watch a scene with tacrom sensors in MuJoCo's viewer.

    python -m tacrom.view scene.xml [--seconds S] [--sensor NAME]

Opens MuJoCo's passive viewer (``mujoco.viewer.launch_passive``) on the scene, with the
*contact point* and *contact force* flags on, so that the plugin's ``visualize`` callback
draws each sensor's deformed gel (thin tiles coloured by depth, at most 400 geoms per
sensor) and, with contact forces shown, the sensor's total force as an arrow. It steps the
simulation in real time (as fast as the sensors allow, when they are slower) and shows
each sensor's images beside the scene, drawn into the viewer with ``Handle.set_images``:
the depth image (in the tiles' colours: grey where flat, through blue to red at the
frame's deepest point, at least 0.1 mm) and,
when the sensor outputs it, the RGB tactile image (with the markers drawn in, when
configured). A text overlay gives each sensor's deepest point, force and the real-time
factor. Toggle the drawing with the viewer's own contact-point / contact-force switches.

With a ``mujoco`` whose viewer has no ``set_images``, the images are written as PNGs into
``--png-dir`` (default ``out/view``) once a second instead, and their paths printed.

The viewer needs a display: without one (no ``DISPLAY`` or ``WAYLAND_DISPLAY``, GLFW
cannot start, or no window opens within 30 s) it exits with status 2 and a message saying
so. Offscreen, use ``mujoco.Renderer`` with
``MUJOCO_GL=egl`` (the callback's geoms are in every ``mjv_updateScene``) or
``tacrom.save_png``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import threading
import time
from typing import Dict, List, Optional, Sequence, Tuple

import mujoco
import numpy as np

import tacrom

#: Height (pixels) of each image drawn into the viewer.
PANEL_HEIGHT = 180
#: Images are refreshed at most this often (seconds of wall time).
IMAGE_PERIOD = 0.1
#: Depth images map this depth (m) or the frame's deepest point, whichever is larger, to white.
DEPTH_FLOOR = 1e-4
#: The viewer is synced at most this often (seconds of wall time).
FRAME_PERIOD = 1.0 / 60.0
#: Distance (m) of the camera from the first sensor's site: four default gel widths.
CAMERA_DISTANCE = 0.12
#: How long (s) the viewer may take to open its window.
LAUNCH_TIMEOUT = 30.0
#: When the simulation falls this far behind the wall clock (s), it stops catching up.
MAX_LAG = 0.1


class ViewError(RuntimeError):
    """The scene cannot be shown (no display, no such sensor, ...)."""


def tacrom_sensors(model: mujoco.MjModel, name: Optional[str] = None) -> List[str]:
    """Names of the scene's tacrom sensors, or just ``name`` (which must be one).

    Unnamed sensors are listed by their id, as ``"#<id>"``."""
    found = []
    for sid in range(model.nsensor):
        if model.sensor_plugin[sid] < 0:
            continue
        try:
            tacrom.layout(model, sid)
        except ValueError:
            continue  # a plugin sensor, but not a tacrom one
        found.append(model.sensor(sid).name or f"#{sid}")
    if name is not None:
        if name not in found:
            raise ViewError(
                f"no tacrom sensor named {name!r} in the scene; its tacrom sensors: "
                + (", ".join(found) if found else "none")
            )
        return [name]
    if not found:
        raise ViewError("the scene has no tacrom.tactile sensor")
    return found


def _sensor_key(model: mujoco.MjModel, name: str):
    return int(name[1:]) if name.startswith("#") else name


def _sensor_id(model: mujoco.MjModel, name: str) -> int:
    key = _sensor_key(model, name)
    if isinstance(key, int):
        return key
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, key)


#: The depth colours of the scene's gel tiles (``tacrom::visual``), on the 8-bit scale: the
#: flat gel's grey, blue at half the deepest point, red at the deepest.
DEPTH_COLOURS = np.array([[184, 189, 199], [38, 115, 242], [242, 51, 25]], dtype=np.float64)


def depth_to_rgb(depth: np.ndarray, vmax: Optional[float] = None) -> np.ndarray:
    """A (H, W) depth image as uint8 (H, W, 3), coloured as the viewer colours the gel:
    grey where flat, through blue to red at ``vmax`` (default: the image's deepest point,
    at least :data:`DEPTH_FLOOR`)."""
    d = np.nan_to_num(np.asarray(depth, dtype=np.float64))
    top = vmax if vmax else max(float(d.max(initial=0.0)), DEPTH_FLOOR)
    f = np.clip(d / top, 0.0, 1.0)
    stops = np.linspace(0.0, 1.0, len(DEPTH_COLOURS))
    rgb = np.stack([np.interp(f, stops, DEPTH_COLOURS[:, k]) for k in range(3)], axis=-1)
    return (rgb + 0.5).astype(np.uint8)


def aim_camera(
    cam: mujoco.MjvCamera, model: mujoco.MjModel, data: mujoco.MjData, sensor: str
) -> None:
    """Points the free camera at the site of ``sensor``, from above and aside,
    :data:`CAMERA_DISTANCE` away (the viewer's default frames the whole scene, where a
    30 mm gel can be a few pixels)."""
    site = model.sensor_objid[_sensor_id(model, sensor)]
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = data.site_xpos[site]
    cam.distance = CAMERA_DISTANCE
    cam.azimuth = 135.0
    cam.elevation = -35.0


def sensor_images(
    model: mujoco.MjModel, data: mujoco.MjData, name: str
) -> List[Tuple[str, np.ndarray]]:
    """The images of sensor ``name`` to show: ``("depth", uint8 (H, W, 3))`` when it has a
    depth image, ``("rgb", ...)`` when it outputs ``rgb`` (markers drawn in, when
    configured); labelled ``"<name> depth"`` and so on."""
    out = tacrom.outputs(model, data, _sensor_key(model, name))
    images = []
    if "depth" in out:
        images.append((f"{name} depth", depth_to_rgb(out["depth"])))
    if "rgb" in out:
        rgb = np.clip(np.nan_to_num(out["rgb"]) + 0.5, 0, 255).astype(np.uint8)
        images.append((f"{name} rgb", rgb))
    return images


def sensor_summary(model: mujoco.MjModel, data: mujoco.MjData, name: str) -> str:
    """One line on sensor ``name``: its deepest point and, when it outputs it, its force."""
    out = tacrom.outputs(model, data, _sensor_key(model, name))
    parts = [name]
    if "depth" in out:
        parts.append(f"depth {1e3 * float(np.max(out['depth'], initial=0.0)):.3f} mm")
    if "force" in out:
        parts.append(f"|F| {float(np.linalg.norm(out['force'])):.3f} N")
    return "  ".join(parts)


def resize(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """``image`` scaled to ``height`` x ``width`` pixels (nearest pixel)."""
    h, w = image.shape[:2]
    rows = np.minimum((np.arange(height) + 0.5) * h / height, h - 1).astype(int)
    cols = np.minimum((np.arange(width) + 0.5) * w / width, w - 1).astype(int)
    return np.ascontiguousarray(image[rows][:, cols])


def layout_panels(
    viewport: Tuple[int, int, int, int],
    shapes: Sequence[Tuple[int, int]],
    margin: int = 4,
    max_height: int = PANEL_HEIGHT,
    max_width_fraction: float = 0.35,
) -> List[Optional[Tuple[int, int, int, int]]]:
    """Places images of ``shapes`` ((height, width) each) in a column at the right edge of
    ``viewport`` ((left, bottom, width, height), pixels, origin bottom-left), top down, each
    scaled (aspect kept) to at most ``max_height`` pixels high, a share of the viewport's
    height, and ``max_width_fraction`` of its width: one ``(left, bottom, width, height)``
    per image, ``None`` where there is no room for one at least 16 pixels high."""
    left, bottom, width, height = viewport
    if not shapes:
        return []
    share = (height - margin * (len(shapes) + 1)) / len(shapes)
    placed: List[Optional[Tuple[int, int, int, int]]] = []
    top = bottom + height - margin
    for h, w in shapes:
        ph = int(min(max_height, share, max_width_fraction * width * h / w))
        pw = max(1, round(w * ph / h))
        x, y = left + width - margin - pw, top - ph
        if ph < 16 or x < left or y < bottom:
            placed.append(None)
            continue
        placed.append((x, y, pw, ph))
        top = y - margin
    return placed


def show_contacts(opt: mujoco.MjvOption) -> None:
    """Turns on the flags the tacrom callback draws with: contact points (the gel surface)
    and contact forces (the surface and the force arrow)."""
    opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTPOINT] = 1
    opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTFORCE] = 1


def require_display() -> None:
    """Raises :class:`ViewError` unless a window can be opened: a display is named
    (``DISPLAY`` or ``WAYLAND_DISPLAY``; not needed on macOS or Windows), ``mujoco.viewer``
    imports, and GLFW initialises."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise ViewError(
            "no display: DISPLAY and WAYLAND_DISPLAY are unset. tacrom.view opens a window; "
            "run it where a display is available (or under xvfb-run / X forwarding). "
            "Offscreen, render with mujoco.Renderer (MUJOCO_GL=egl) or write images with "
            "tacrom.save_png."
        )
    try:
        import glfw
        from mujoco import viewer  # noqa: F401  (needs GLFW's library)
    except (ImportError, RuntimeError) as e:
        raise ViewError(f"MuJoCo's viewer is unavailable: {e}") from e
    if not glfw.init():
        raise ViewError(
            "no display: GLFW could not initialise (is the X server or Wayland compositor "
            f"named by DISPLAY={os.environ.get('DISPLAY', '')!r} reachable?)"
        )
    glfw.terminate()


def _launch(mujoco_viewer, model, data, timeout: float = LAUNCH_TIMEOUT):
    """``launch_passive``, with a time limit on Linux: when its window fails to open (an
    exception in the viewer's thread), ``launch_passive`` waits forever. Returns the handle
    and the helper thread that called it (``None`` elsewhere)."""
    if not sys.platform.startswith("linux"):
        return mujoco_viewer.launch_passive(model, data), None
    box: Dict[str, object] = {}

    def call():
        try:
            box["handle"] = mujoco_viewer.launch_passive(model, data)
        except Exception as e:  # reported below, in the caller's thread
            box["error"] = e

    helper = threading.Thread(target=call, daemon=True)
    helper.start()
    helper.join(timeout)
    if "error" in box:
        raise ViewError(f"MuJoCo's viewer failed to start: {box['error']}")
    if "handle" not in box:
        raise ViewError(
            f"MuJoCo's viewer opened no window within {timeout:.0f} s (no OpenGL on this "
            "display?)"
        )
    return box["handle"], helper


def _write_pngs(model, data, sensors: Sequence[str], folder: pathlib.Path) -> List[pathlib.Path]:
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name in sensors:
        for label, img in sensor_images(model, data, name):
            path = folder / (label.replace(" ", "_").replace("#", "sensor") + ".png")
            tacrom.save_png(path, img)
            written.append(path)
    return written


def run(
    xml: pathlib.Path,
    seconds: Optional[float] = None,
    sensor: Optional[str] = None,
    png_dir: pathlib.Path = pathlib.Path("out/view"),
) -> None:
    """Opens the viewer on the scene ``xml`` and runs it for ``seconds`` of simulated time
    (until the window closes when ``None``), showing ``sensor`` (default: every tacrom
    sensor)."""
    tacrom.load()
    model = mujoco.MjModel.from_xml_path(str(xml))
    data = mujoco.MjData(model)
    sensors = tacrom_sensors(model, sensor)
    require_display()
    from mujoco import viewer as mujoco_viewer

    before = set(threading.enumerate())
    viewer, helper = _launch(mujoco_viewer, model, data)
    # The viewer's own thread: joined before returning, so that it has stopped rendering
    # when the process exits (GLFW terminates at exit, and a window still drawing then
    # crashes the process).
    ui_threads = [t for t in threading.enumerate() if t not in before and t is not helper]
    with viewer.lock():
        show_contacts(viewer.opt)
        aim_camera(viewer.cam, model, data, sensors[0])
    images_in_viewer = hasattr(viewer, "set_images")
    if images_in_viewer:
        print("tacrom.view: the sensors' images are drawn at the right of the viewer")
    else:
        print(f"tacrom.view: this mujoco's viewer cannot draw images; writing PNGs to {png_dir}")
    wall0, sim0 = time.perf_counter(), data.time
    last_images = last_pngs = -np.inf
    factor = 1.0
    last_sim, last_wall = data.time, wall0
    try:
        while viewer.is_running() and (seconds is None or data.time < seconds):
            now = time.perf_counter()
            # Step until the simulation catches up with the wall clock, or the frame's
            # time is up (sensors slower than real time: as fast as they allow).
            target = sim0 + (now - wall0)
            if target - data.time > MAX_LAG:
                wall0, sim0 = now, data.time
                target = data.time + model.opt.timestep
            frame_end = now + FRAME_PERIOD
            # The real-time factor: simulated over wall time since the last frame.
            if now > last_wall:
                factor = 0.9 * factor + 0.1 * (data.time - last_sim) / (now - last_wall)
            last_sim, last_wall = data.time, now
            # The viewer draws its own copy of the data (taken by sync), so stepping
            # needs no lock.
            while data.time < target and time.perf_counter() < frame_end:
                mujoco.mj_step(model, data)
            viewer.sync()
            now = time.perf_counter()
            if images_in_viewer and now - last_images >= IMAGE_PERIOD:
                last_images = now
                _show_images(viewer, model, data, sensors, factor)
            elif not images_in_viewer and now - last_pngs >= 1.0:
                last_pngs = now
                for p in _write_pngs(model, data, sensors, png_dir):
                    print(f"  t = {data.time:7.3f} s: {p}")
            spare = frame_end - time.perf_counter()
            if data.time >= target and spare > 0:
                time.sleep(spare)
    finally:
        viewer.close()
        for t in ui_threads:
            t.join(timeout=10.0)


def _show_images(viewer, model, data, sensors: Sequence[str], factor: float) -> None:
    images = [img for name in sensors for _, img in sensor_images(model, data, name)]
    viewport = viewer.viewport
    if viewport is not None:
        rects = layout_panels(
            (viewport.left, viewport.bottom, viewport.width, viewport.height),
            [img.shape[:2] for img in images],
        )
        viewer.set_images(
            [
                (mujoco.MjrRect(*r), resize(img, r[3], r[2]))
                for r, img in zip(rects, images)
                if r is not None
            ]
        )
    lines = [sensor_summary(model, data, s) for s in sensors]
    viewer.set_texts(
        (
            mujoco.mjtFontScale.mjFONTSCALE_150,
            mujoco.mjtGridPos.mjGRID_BOTTOMLEFT,
            "\n".join(lines + ["real time"]),
            "\n".join([""] * len(lines) + [f"x {factor:.2f}"]),
        )
    )


def parse_args(argv: Optional[Sequence[str]] = None) -> argparse.Namespace:
    """The command line of ``python -m tacrom.view``."""
    parser = argparse.ArgumentParser(
        prog="python -m tacrom.view",
        description="Show a scene with tacrom sensors in MuJoCo's viewer: the deformed gel "
        "and the force drawn into the scene, the sensors' images beside it.",
    )
    parser.add_argument("scene", type=pathlib.Path, help="MJCF scene with tacrom sensors")
    parser.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="simulated seconds to run (default: until the window is closed)",
    )
    parser.add_argument(
        "--sensor", default=None, help="show only this tacrom sensor (default: all of them)"
    )
    parser.add_argument(
        "--png-dir",
        type=pathlib.Path,
        default=pathlib.Path("out/view"),
        help="where to write the images when the viewer cannot draw them (default out/view)",
    )
    args = parser.parse_args(argv)
    if args.seconds is not None and not args.seconds > 0:
        parser.error("--seconds must be positive")
    return args


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point; returns the exit status (2 with a message when the scene cannot be
    shown)."""
    args = parse_args(argv)
    if not args.scene.is_file():
        print(f"tacrom.view: no such scene file: {args.scene}", file=sys.stderr)
        return 2
    try:
        run(args.scene, args.seconds, args.sensor, args.png_dir)
    except (ViewError, ValueError) as e:  # MuJoCo reports a bad scene as ValueError
        print(f"tacrom.view: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
