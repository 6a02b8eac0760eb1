"""Presses a sphere into the tactile sensor of examples/press.xml, writes depth images (and,
with the `rgb` and `pressure` outputs, the RGB tactile images and the contact pressure
beside them) as PNG and prints the time of one sensor evaluation for each physics mode.
The markers are drawn into the RGB images. `pressure` and `markers` need a gel, so the rigid
mode leaves them out.

    .venv/bin/python examples/demo.py --out out/demo --physics rigid coarse
    .venv/bin/python examples/demo.py --outputs depth      # depth images only

A mode may name a solver or one of rom's shipped models after a dash (``examples/modes.py``):
``coarse-linear`` is the coarse mode with ``solver="linear"`` (the small-strain gel, on
which ``rom`` runs by default); ``rom-default`` is rom with ``model="rom-default"``, on the
relaxation's gel, as ``physics="rom"`` ran before.
"""

from __future__ import annotations

import argparse
import pathlib
import re
import statistics
import time

import mujoco
import numpy as np

import tacrom
from modes import mode_config

HERE = pathlib.Path(__file__).resolve().parent


def model_for(physics: str, outputs: list, xml_path: pathlib.Path) -> mujoco.MjModel:
    xml = xml_path.read_text()
    config = mode_config(physics)
    extra = "".join(
        f'<config key="{k}" value="{v}"/>' for k, v in config.items() if k != "physics"
    )
    xml = re.sub(
        r'<config key="physics" value="[^"]*"/>',
        f'<config key="physics" value="{config["physics"]}"/>{extra}',
        xml,
    )
    value = " ".join(outputs)
    xml = re.sub(r'key="outputs" value="[^"]*"', f'key="outputs" value="{value}"', xml)
    return mujoco.MjModel.from_xml_string(xml)


def run(
    physics: str, outputs: list, out: pathlib.Path, frames: int, xml_path: pathlib.Path
) -> None:
    if physics == "rigid":
        outputs = [o for o in outputs if o not in ("force", "pressure", "shear", "markers")]
    model = model_for(physics, outputs, xml_path)
    data = mujoco.MjData(model)
    steps_per_frame = 50
    step_times = []
    t_total = time.perf_counter()
    for frame in range(frames):
        depth_target = 1e-3 * frame / max(frames - 1, 1)
        data.ctrl[0] = depth_target
        for _ in range(steps_per_frame):
            # Each mj_step evaluates the sensor once, at the indenter's new pose: a
            # continuous moving press.
            t0 = time.perf_counter()
            mujoco.mj_step(model, data)
            step_times.append(time.perf_counter() - t0)
        img = tacrom.depth(model, data, "touch")
        path = out / f"{physics}_frame{frame:02d}.png"
        tacrom.save_png(path, img, vmax=1.2e-3)
        written = [path]
        if "rgb" in outputs:
            rgb_path = out / f"{physics}_frame{frame:02d}_rgb.png"
            tacrom.save_png(rgb_path, tacrom.rgb(model, data, "touch"))
            written.append(rgb_path)
        if "pressure" in outputs:
            p_path = out / f"{physics}_frame{frame:02d}_pressure.png"
            p = tacrom.pressure(model, data, "touch")
            tacrom.save_png(p_path, p, vmax=max(p.max(), 1.0))
            written.append(p_path)
        press = data.qpos[0] * 1e3
        print(
            f"  {physics:6s} frame {frame:2d}: press {press:6.3f} mm  max depth "
            f"{img.max() * 1e3:6.3f} mm  -> {', '.join(str(p) for p in written)}"
        )
    # The same steps without the sensor: the difference is the sensor's cost.
    bare = mujoco.MjData(model)
    mujoco.mj_copyData(bare, model, data)
    sensor_bit = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
    model.opt.disableflags |= sensor_bit
    bare_times = []
    for _ in range(200):
        t0 = time.perf_counter()
        mujoco.mj_step(model, bare)
        bare_times.append(time.perf_counter() - t0)
    model.opt.disableflags &= ~sensor_bit
    ms = np.array(step_times) * 1e3
    sensor_ms = statistics.median(ms) - statistics.median(bare_times) * 1e3
    print(
        f"{physics}: sensor evaluation median {sensor_ms:.2f} ms (mj_step median "
        f"{statistics.median(ms):.2f} ms, p90 {np.percentile(ms, 90):.2f} ms, with sensors off "
        f"{statistics.median(bare_times) * 1e3:.3f} ms) over {len(ms)} steps of a moving "
        f"press, {model.sensor_dim[0]} values; whole run {time.perf_counter() - t_total:.2f} s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("out/demo"))
    parser.add_argument("--physics", nargs="+", default=["rigid"])
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--xml", type=pathlib.Path, default=HERE / "press.xml")
    parser.add_argument(
        "--outputs",
        nargs="+",
        default=["depth", "rgb", "markers", "pressure"],
        help="the sensor's outputs (depth is always among them); with rgb and pressure, "
        "their images are written beside the depth images (pressure scaled to its peak; "
        "with markers, the markers are drawn into rgb)",
    )
    args = parser.parse_args()
    outputs = args.outputs if "depth" in args.outputs else ["depth", *args.outputs]
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"tacrom plugin: {tacrom.load()}")
    for physics in args.physics:
        run(physics, outputs, args.out, args.frames, args.xml)


if __name__ == "__main__":
    main()
