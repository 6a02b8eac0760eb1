"""tacrom: a high-detail tactile sensor for MuJoCo.

Importing ``mujoco`` registers the ``tacrom.tactile`` sensor plugin through MuJoCo's
``mujoco.plugins`` entry point; :func:`load` does it explicitly. Sensor outputs are read
with :func:`depth`, :func:`force`, :func:`contact`, :func:`rgb`, :func:`pressure`,
:func:`shear` and :func:`markers`, or all at once with :func:`outputs`.

With Gymnasium installed, importing tacrom registers its environments,
``tacrom/Press-v1`` and ``tacrom/GripperLift-v1`` (:mod:`tacrom.envs`).

Image layout: row-major (H, W) (``rgb``: (H, W, 3)). Row 0 is the +y edge of the sensor
site's frame and column 0 the -x edge: the gel seen from the indenter's side, x to the
right, y up.

Camera (sensor attributes ``camera`` and ``index``): ``camera="orthographic"`` (default)
shows, at each pixel, the surface straight above its centre. ``camera="pinhole D"`` puts a
pinhole on the gel's axis ``D`` metres below the gel's bottom face, looking up through the
gel, whose refractive index relative to the camera's medium is ``index`` (default 1, valid
1 to 3; about 1.4 for silicone seen from air). Each pixel's ray meets the undeformed face
at the pixel's orthographic centre, so without contact both cameras show the same image;
in contact, ``depth`` is the indentation where the refracted ray meets the surface, and
``rgb``, ``pressure``, ``shear`` and ``contact`` are sampled at that point. ``markers`` is
for the orthographic camera only. See ``docs/camera.md``.
"""

from __future__ import annotations

import ctypes
import json
import os
import pathlib
import struct
import zlib
from typing import Dict, Mapping, Optional

import numpy as np

__all__ = [
    "load",
    "library_path",
    "output_table",
    "attribute_table",
    "layout",
    "outputs",
    "depth",
    "force",
    "contact",
    "rgb",
    "pressure",
    "shear",
    "markers",
    "save_png",
]

PLUGIN_NAME = "tacrom.tactile"
_lib: Optional[ctypes.CDLL] = None


def library_path() -> pathlib.Path:
    """Path of the plugin library: ``$TACROM_PLUGIN`` or the copy inside this package."""
    env = os.environ.get("TACROM_PLUGIN")
    if env:
        return pathlib.Path(env).resolve()
    return pathlib.Path(__file__).resolve().parent / "_lib" / "libtacrom.so"


def load(path: Optional[os.PathLike] = None) -> pathlib.Path:
    """Registers the plugin with MuJoCo (once per process) and returns the library path."""
    global _lib
    lib_path = pathlib.Path(path).resolve() if path else library_path()
    if _lib is not None:
        return lib_path
    if not lib_path.is_file():
        raise FileNotFoundError(
            f"tacrom plugin library not found at {lib_path}; run `make build` in the tacrom "
            "checkout or set TACROM_PLUGIN"
        )
    # libmujoco is already loaded by `import mujoco`; the library's constructor registers
    # the plugin with it.
    _lib = ctypes.CDLL(str(lib_path))
    _lib.tacrom_sensor_outputs.restype = ctypes.c_int
    _lib.tacrom_sensor_outputs.argtypes = [
        ctypes.c_void_p,
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_int,
    ]
    _lib.tacrom_output_table.restype = ctypes.c_int
    _lib.tacrom_output_table.argtypes = [ctypes.c_char_p, ctypes.c_int]
    _lib.tacrom_attribute_table.restype = ctypes.c_int
    _lib.tacrom_attribute_table.argtypes = [ctypes.c_char_p, ctypes.c_int]
    _lib.tacrom_sensor_file.restype = ctypes.c_int
    _lib.tacrom_sensor_file.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_int]
    return lib_path


def _register_with_mujoco() -> None:
    """Entry point called by ``import mujoco``."""
    load()


def _sensor_id(model, sensor) -> int:
    import mujoco

    if isinstance(sensor, (int, np.integer)):
        sid = int(sensor)
    else:
        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, sensor)
    if not 0 <= sid < model.nsensor:
        raise KeyError(f"no sensor {sensor!r} in the model")
    if model.sensor_plugin[sid] < 0:
        raise ValueError(f"sensor {sensor!r} is not a {PLUGIN_NAME} sensor")
    return sid


def _json_from(call, what: str):
    """Calls ``call(buf, len)`` of the library with a growing buffer and parses the JSON it
    writes; a negative return raises ``ValueError`` with the library's reason."""
    size = 4096
    while True:
        buf = ctypes.create_string_buffer(size)
        n = call(buf, size)
        if n < 0:
            raise ValueError(f"{what}: {buf.value.decode(errors='replace')}")
        if n < size:
            return json.loads(buf.value.decode())
        size = n + 1


def output_table() -> list:
    """Every output the plugin can produce, from its output table: a list of
    ``{"name", "doc", "unit", "shape", "needs_gel"}`` (shape ``["H", "W"]`` for images)."""
    load()
    return _json_from(_lib.tacrom_output_table, "tacrom output table")


def attribute_table() -> list:
    """Every configuration attribute of the sensor, from the plugin's attribute table: a
    list of ``{"name", "meaning", "unit", "default", "valid"}`` (``default`` as written in
    MJCF, or in words where it depends on other attributes; ``valid`` in words)."""
    load()
    return _json_from(_lib.tacrom_attribute_table, "tacrom attribute table")


def sensor_file(value: str) -> Dict[str, str]:
    """The attributes a sensor file gives (``sensor="..."``: a file, its folder, or a shipped
    sensor's name such as ``"gelsight-mini"``), as MJCF text, paths relative to the working
    directory, with the file's own path under ``"path"``. Raises ``ValueError`` naming the
    fault of a missing or bad file."""
    load()
    return _json_from(
        lambda buf, size: _lib.tacrom_sensor_file(str(value).encode(), buf, size),
        f"sensor file {value!r}",
    )


def attribute(config: Mapping[str, object], name: str) -> str:
    """The value attribute ``name`` takes in a sensor configured by ``config`` (MJCF
    attributes as a mapping): as ``config`` gives it, else as its sensor file
    (``config["sensor"]``) gives it, else its default."""
    if config.get(name):
        return str(config[name])
    if config.get("sensor"):
        given = sensor_file(str(config["sensor"]))
        if name in given:
            return given[name]
    return attribute_default(name)


def attribute_default(name: str) -> str:
    """The default of configuration attribute ``name`` as written in MJCF."""
    for row in attribute_table():
        if row["name"] == name:
            return row["default"]
    raise KeyError(f"{PLUGIN_NAME} has no attribute {name!r}")


def layout(model, sensor) -> Dict[str, object]:
    """The sensordata layout of a tacrom sensor, as the plugin's output table declares it.

    Returns ``{"width", "height", "markers", "size", "outputs": {name: {"offset", "shape",
    "unit"}}}`` with the outputs in sensordata order, offsets relative to the sensor's first
    value; ``markers`` is the marker grid ``[NX, NY]``; ``solver`` is the gel's solver
    ``{"name", "fallback", "why"}`` (why the plugin chose it; ``None`` for ``rigid``).
    """
    load()
    sid = _sensor_id(model, sensor)
    table = _json_from(
        lambda buf, size: _lib.tacrom_sensor_outputs(ctypes.c_void_p(model._address), sid, buf, size),
        f"sensor {sensor!r} is not a valid {PLUGIN_NAME} sensor",
    )
    table["outputs"] = {
        o["name"]: {"offset": o["offset"], "shape": tuple(o["shape"]), "unit": o["unit"]}
        for o in table["outputs"]
    }
    return table


def outputs(model, data, sensor) -> Dict[str, np.ndarray]:
    """All configured outputs of ``sensor``, each shaped as the plugin declares it: images
    (H, W) (or (H, W, C)), vectors (n,)."""
    lay = layout(model, sensor)
    sid = _sensor_id(model, sensor)
    adr = model.sensor_adr[sid]
    values = data.sensordata[adr : adr + model.sensor_dim[sid]]
    result = {}
    for name, o in lay["outputs"].items():
        length = int(np.prod(o["shape"]))
        result[name] = np.array(values[o["offset"] : o["offset"] + length]).reshape(o["shape"])
    return result


def _one(model, data, sensor, name: str) -> np.ndarray:
    out = outputs(model, data, sensor)
    if name not in out:
        raise KeyError(f"sensor {sensor!r} does not output {name!r}; add it to its 'outputs'")
    return out[name]


def depth(model, data, sensor) -> np.ndarray:
    """Depth image (H, W) in metres, positive into the gel: the indentation of the surface
    point each pixel sees (straight above it, or along the pinhole's refracted ray with
    ``camera="pinhole D"``)."""
    return _one(model, data, sensor, "depth")


def force(model, data, sensor) -> np.ndarray:
    """Total force of the gel on the indenters (3,), newtons, sensor frame."""
    return _one(model, data, sensor, "force")


def contact(model, data, sensor) -> np.ndarray:
    """Contact mask (H, W): 1 where an indenter touches the gel."""
    return _one(model, data, sensor, "contact")


def rgb(model, data, sensor) -> np.ndarray:
    """RGB tactile image (H, W, 3): what a GelSight-type sensor's camera sees, floats on the
    8-bit scale 0..255, pixel for pixel on the depth image. The deformed surface is shaded
    by a red, a green and a blue light (at azimuths 90, 210 and 330 degrees from +x, red at
    the image's top, 30 degrees above the gel); the flat gel shows a uniform background.
    With the ``optics`` attribute (a file written by ``tacrom calibrate``), a calibrated
    gradient-to-colour table over its background image (resampled to (H, W)) replaces that
    shading. Write it with :func:`save_png`."""
    return _one(model, data, sensor, "rgb")


def pressure(model, data, sensor) -> np.ndarray:
    """Normal contact pressure image (H, W) in pascals, positive where the indenters press
    the gel, pixel for pixel on the depth image. Summed over the pixels times the pixel area
    it gives the normal force ``force(...)[2]`` wherever the contact lies inside the image
    (orthographic camera; a pinhole camera samples it where its rays meet the surface, so
    the sum is only close). Needs a gel (not ``physics="rigid"``); ``rom`` reports its
    coarse gel's pressure."""
    return _one(model, data, sensor, "pressure")


def shear(model, data, sensor) -> np.ndarray:
    """Shear image (H, W, 2) in metres: the in-plane displacement (sensor frame x, then y)
    of the gel surface point seen at each pixel, zero where the gel is undeformed. Not with
    ``physics="rigid"``; with ``rom``, from its coarse gel (the decoder restores depth
    only)."""
    return _one(model, data, sensor, "shear")


def markers(model, data, sensor) -> np.ndarray:
    """The markers printed on the gel, (NX * NY, 4): per marker, the column and row of
    where the camera sees it (pixels, continuous: ``c`` is the centre of column ``c``, row 0
    the +y edge), then its displacement along x and y (metres, sensor frame).

    The ``markers`` attribute sets the grid (default ``"9 7"``), spread evenly over the
    image; markers are in the image's reading order (first row at +y, first column at -x),
    so ``markers(...).reshape(NY, NX, 4)`` lays them out as seen. A marker's rest position
    in pixels is its position less its displacement: ``col - dx / (fov_x / W)``,
    ``row + dy / (fov_y / H)``. Not with ``physics="rigid"``; with ``rom``, from its coarse
    gel. Orthographic camera only (refused at load with ``camera="pinhole D"``)."""
    return _one(model, data, sensor, "markers")


def save_png(path: os.PathLike, image: np.ndarray, vmax: Optional[float] = None) -> None:
    """Writes an 8-bit PNG: a (H, W) array as greyscale, 0 -> black and ``vmax`` (default:
    the image's largest value) -> white; a (H, W, 3) array (such as :func:`rgb`) as colour,
    0 -> black and ``vmax`` (default 255) -> full scale."""
    img = np.asarray(image, dtype=np.float64)
    colour = img.ndim == 3 and img.shape[2] == 3
    if img.ndim != 2 and not colour:
        raise ValueError("save_png expects a (H, W) or (H, W, 3) array")
    if vmax:
        top = float(vmax)
    elif colour:
        top = 255.0
    else:
        top = float(img.max()) if img.size and img.max() > 0 else 1.0
    pixels = np.clip(np.nan_to_num(img) / top * 255.0 + 0.5, 0, 255).astype(np.uint8)
    h, w = pixels.shape[:2]
    raw = b"".join(b"\x00" + pixels[r].tobytes() for r in range(h))

    def chunk(tag: bytes, payload: bytes) -> bytes:
        return (
            struct.pack(">I", len(payload))
            + tag
            + payload
            + struct.pack(">I", zlib.crc32(tag + payload) & 0xFFFFFFFF)
        )

    colour_type = 2 if colour else 0  # PNG: 2 truecolour (RGB), 0 greyscale
    png = b"\x89PNG\r\n\x1a\n"
    png += chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 6))
    png += chunk(b"IEND", b"")
    pathlib.Path(path).write_bytes(png)


def _register_envs() -> None:
    """Registers the Gymnasium environments (``tacrom/Press-v1``, ``tacrom/GripperLift-v1``,
    :mod:`tacrom.envs`) when Gymnasium is installed."""
    try:
        import gymnasium  # noqa: F401
    except ImportError:
        return
    from tacrom.envs import register_envs

    register_envs()


_register_envs()
