"""Builds the tacrom wheel: the Python package with the plugin library
(``tacrom/_lib/libtacrom.so``), the shipped reduced-order models
(``tacrom/models/rom-default`` and, for ``solver="linear"``, ``tacrom/models/rom-linear``
and ``rom-linear-narrow``, the default on gels of 3.5 mm and more: manifests and the ONNX
files they name), the shipped sensors (``tacrom/sensors``:
``gelsight-mini``'s sensor file, optics and licence) and the environments' scenes
(``tacrom/envs/assets``: ``examples/gripper.xml`` and its mesh).

    .venv/bin/python python/build_wheel.py --out dist      # what `make wheel` runs

The package is staged in a scratch folder so that the checkout keeps one copy of the models
and the scenes. The library looks for ``models/<name>`` beside itself, walking up from
``_lib`` (``tacrom::rom::shipped_model_dir``), so ``tacrom/models/rom-default`` is where an
installed package's ``physics="rom"`` finds it. The wheel is tagged ``py3-none-<platform>``:
the library is native code but does not depend on the Python version.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import shutil
import subprocess
import sys
import sysconfig
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
MODELS = ("rom-default", "rom-linear", "rom-linear-narrow")
SENSORS = ("gelsight-mini",)


def sensor_files(sensor_dir: pathlib.Path) -> list[pathlib.Path]:
    """What of a shipped sensor the run time needs: its sensor file, the optics file it
    names and that file's background image, and its licences."""
    sensor = sensor_dir / "sensor.json"
    if not sensor.is_file():
        raise SystemExit(f"no {sensor_dir.name} sensor in {sensor_dir.parent}")
    files = [sensor] + sorted(sensor_dir.glob("LICENSE*"))
    optics_name = json.loads(sensor.read_text())["attributes"].get("optics")
    if optics_name:
        optics = sensor_dir / optics_name
        files += [optics, sensor_dir / json.loads(optics.read_text())["background"]]
    return files


def model_files(model_dir: pathlib.Path) -> list[pathlib.Path]:
    """What of a model directory the run time needs: its manifest and the ONNX files the
    manifest names (not its training weights, its validation pairs, or a float decoder
    that an 8-bit copy replaces)."""
    manifest = model_dir / "manifest.json"
    if not manifest.is_file():
        raise SystemExit(f"no {model_dir.name} model in {model_dir.parent}")
    files = json.loads(manifest.read_text())["files"]
    return [manifest] + [model_dir / f["path"] for f in files.values()]


def stage(dest: pathlib.Path) -> None:
    """Copies the package, the library, the model and the scenes into ``dest``."""
    python = ROOT / "python"
    lib = python / "tacrom" / "_lib" / "libtacrom.so"
    if not lib.is_file():
        raise SystemExit(f"{lib} is missing: run `make build` first")
    shutil.copy2(python / "pyproject.toml", dest / "pyproject.toml")
    shutil.copytree(
        python / "tacrom",
        dest / "tacrom",
        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "models", "assets"),
    )
    for model in MODELS:
        model_dir = dest / "tacrom" / "models" / model
        model_dir.mkdir(parents=True)
        for f in model_files(ROOT / "models" / model):
            shutil.copy2(f, model_dir / f.name)
    for sensor in SENSORS:
        sensor_dir = dest / "tacrom" / "sensors" / sensor
        sensor_dir.mkdir(parents=True)
        for f in sensor_files(ROOT / "sensors" / sensor):
            shutil.copy2(f, sensor_dir / f.name)
    assets = dest / "tacrom" / "envs" / "assets"
    (assets / "meshes").mkdir(parents=True)
    shutil.copy2(ROOT / "examples" / "gripper.xml", assets / "gripper.xml")
    for f in sorted((ROOT / "examples" / "meshes").iterdir()):
        shutil.copy2(f, assets / "meshes" / f.name)
    platform = sysconfig.get_platform().replace("-", "_").replace(".", "_")
    (dest / "setup.cfg").write_text(
        f"[bdist_wheel]\npython_tag = py3\nplat_name = {platform}\n"
    )


def build(out: pathlib.Path) -> pathlib.Path:
    """Builds the wheel into ``out`` and returns its path."""
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="tacrom-wheel-") as tmp:
        src = pathlib.Path(tmp) / "src"
        src.mkdir()
        stage(src)
        before = set(out.glob("tacrom-*.whl"))
        subprocess.run(
            [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
             str(src), "-w", str(out)],
            check=True,
        )
    wheels = sorted(out.glob("tacrom-*.whl"), key=lambda p: p.stat().st_mtime)
    if not wheels:
        raise SystemExit(f"pip wheel wrote no tacrom wheel to {out}")
    new = [w for w in wheels if w not in before]
    return (new or wheels)[-1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "dist")
    args = parser.parse_args()
    wheel = build(args.out.resolve())
    print(f"{wheel} ({wheel.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
