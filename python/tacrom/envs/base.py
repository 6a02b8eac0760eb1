"""What the tactile environments share: building the model with the sensors configured,
stepping with one sensor evaluation per environment step, the tactile observations, and
rendering (headless included)."""

from __future__ import annotations

import importlib
import os
import pathlib
import sys
from typing import Mapping, Optional, Sequence

import gymnasium as gym
import mujoco
import numpy as np

import tacrom

#: The physics modes an environment accepts (``fine`` is a reference, far too slow for RL).
PHYSICS = ("rigid", "coarse", "rom")


_SENSOR_BIT = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)


def asset_path(name: str) -> pathlib.Path:
    """A scene file shipped with the package (``tacrom/envs/assets``, in the wheel) or, in a
    checkout, its original in ``examples/``."""
    here = pathlib.Path(__file__).resolve().parent
    for candidate in (here / "assets" / name, here.parents[2] / "examples" / name):
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(
        f"{name} not found in {here / 'assets'} nor in the checkout's examples/ "
        f"({here.parents[2] / 'examples'})"
    )


def configure_sensors(
    spec: mujoco.MjSpec,
    sensors: Sequence[str],
    *,
    physics: Optional[str],
    resolution: tuple[int, int],
    outputs: Sequence[str],
    extra: Optional[Mapping[str, object]] = None,
) -> float:
    """Sets ``physics``, ``resolution`` and ``outputs`` of the named tacrom sensors in
    ``spec``, and any other attributes given in ``extra`` (such as ``tolerance``,
    ``threads`` or ``sensor``, a sensor file or a shipped sensor's name such as
    ``"gelsight-mini"``; docs/configuration.md); the rest stay as the scene has them.
    ``physics=None`` leaves it to the sensor file (or the scene, or the default).
    Returns the thickest of their gels (m), the bound of their depth images."""
    if physics is not None and physics not in PHYSICS:
        raise ValueError(f"physics must be one of {PHYSICS}, not {physics!r}")
    width, height = (int(v) for v in resolution)
    found = {s.name: s for s in spec.sensors}
    thickness = 0.0
    for name in sensors:
        if name not in found:
            raise KeyError(f"the scene has no sensor {name!r}")
        plugin = found[name].plugin
        config = dict(plugin.config)
        config.update({str(k): str(v) for k, v in (extra or {}).items()})
        config.update(resolution=f"{width} {height}", outputs=" ".join(outputs))
        if physics is not None:
            config["physics"] = physics
        elif "sensor" in (extra or {}):
            # The scene's own physics gives way to the sensor file's.
            config.pop("physics", None)
        plugin.config = config
        size = tacrom.attribute(config, "size")
        thickness = max(thickness, float(size.split()[2]))
    return thickness


def _headless() -> bool:
    return sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )


def make_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer``. With ``MUJOCO_GL`` set, or a display, MuJoCo picks the OpenGL
    backend; on a headless Linux machine without ``MUJOCO_GL`` (where MuJoCo's default,
    GLFW, cannot open a context) it uses EGL, then OSMesa. Raises ``RuntimeError`` saying
    what failed when none works."""
    if os.environ.get("MUJOCO_GL") or not _headless():
        try:
            return mujoco.Renderer(model, height, width)
        except Exception as err:  # MuJoCo raises FatalError, ImportError, RuntimeError
            raise RuntimeError(
                f"render_mode='rgb_array' needs an OpenGL context, and MuJoCo could not make "
                f"one (MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r}): {err}"
            ) from err
    from mujoco.rendering.classic import gl_context

    failures = []
    default = gl_context.GLContext
    for backend in ("egl", "osmesa"):
        try:
            module = importlib.import_module(f"mujoco.{backend}")
            # mujoco.Renderer takes its context class from gl_context, chosen from MUJOCO_GL
            # when mujoco was imported; point it at the headless backend for this one call.
            gl_context.GLContext = module.GLContext
            return mujoco.Renderer(model, height, width)
        except Exception as err:
            failures.append(f"{backend}: {type(err).__name__}: {err}")
        finally:
            gl_context.GLContext = default
    raise RuntimeError(
        "render_mode='rgb_array' needs an OpenGL context; on this headless machine none "
        f"could be made ({'; '.join(failures)}). Install EGL (libegl1) or OSMesa "
        "(libosmesa6), or set MUJOCO_GL."
    )


class TactileEnv(gym.Env):
    """Base of the tactile environments: owns the model, the data and the renderer.

    Subclasses build the model (:func:`configure_sensors` on their scene), pass it with
    their sensors' names, build their observation space with :meth:`_tactile_spaces` and
    read the images with :meth:`_tactile_obs`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(
        self,
        model: mujoco.MjModel,
        sensors: Sequence[str],
        *,
        gel_thickness: float,
        frame_skip: int,
        tactile_rgb: bool,
        render_mode: Optional[str],
        render_size: tuple[int, int],
        camera: str,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"not {render_mode!r}"
            )
        if frame_skip < 1:
            raise ValueError(f"frame_skip must be at least 1, not {frame_skip}")
        self.model = model
        self.data = mujoco.MjData(model)
        self.frame_skip = int(frame_skip)
        self.tactile_rgb = bool(tactile_rgb)
        self.render_mode = render_mode
        self.render_size = tuple(int(v) for v in render_size)  # (W, H)
        self.camera = camera
        self._renderer: Optional[mujoco.Renderer] = None
        self.metadata = dict(self.metadata, render_fps=1.0 / self.dt)

        # Where each sensor's images lie in sensordata, read once from the output table.
        self.sensors = list(sensors)
        self._slices = []
        for name in self.sensors:
            lay = tacrom.layout(model, name)
            adr = int(model.sensor_adr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)])
            slices = {}
            for output, o in lay["outputs"].items():
                start = adr + o["offset"]
                slices[output] = (slice(start, start + int(np.prod(o["shape"]))), o["shape"])
            self._slices.append(slices)
        height, width = self._slices[0]["depth"][1]
        self.image_shape = (height, width)
        self.gel_thickness = float(gel_thickness)

    @property
    def dt(self) -> float:
        """Simulated seconds per environment step."""
        return float(self.model.opt.timestep) * self.frame_skip

    def _tactile_spaces(self) -> dict:
        n = len(self.sensors)
        h, w = self.image_shape
        spaces = {
            "tactile_depth": gym.spaces.Box(
                0.0, self.gel_thickness, shape=(n, h, w), dtype=np.float32
            )
        }
        if self.tactile_rgb:
            spaces["tactile_rgb"] = gym.spaces.Box(0, 255, shape=(n, h, w, 3), dtype=np.uint8)
        return spaces

    def _tactile_obs(self) -> dict:
        """The tactile keys of the observation, new arrays each call."""
        values = self.data.sensordata
        depth = np.stack([values[s["depth"][0]] for s in self._slices]).astype(np.float32)
        obs = {"tactile_depth": depth.reshape(len(self.sensors), *self.image_shape)}
        if self.tactile_rgb:
            rgb = np.stack([values[s["rgb"][0]] for s in self._slices])
            rgb = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
            obs["tactile_rgb"] = rgb.reshape(len(self.sensors), *self.image_shape, 3)
        return obs

    def _simulate(self) -> None:
        """``frame_skip`` physics steps with the sensors off, then one ``mj_forward`` that
        evaluates them at the final state: one tactile evaluation per environment step."""
        m, d = self.model, self.data
        m.opt.disableflags |= _SENSOR_BIT
        try:
            # One call for all of them (MuJoCo repeats the step itself): the same steps,
            # without a Python round trip each.
            mujoco.mj_step(m, d, nstep=self.frame_skip)
        finally:
            m.opt.disableflags &= ~_SENSOR_BIT
        mujoco.mj_forward(m, d)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; make the env with "
                            "render_mode='rgb_array'")
            return None
        if self._renderer is None:
            width, height = self.render_size
            self._renderer = make_renderer(self.model, height, width)
        self._renderer.update_scene(self.data, camera=self.camera)
        return self._renderer.render().copy()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

