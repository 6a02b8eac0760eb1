"""Grasps, lifts, holds and slides each object of examples/gripper.xml with the tactile
gripper, and writes both fingertips' depth and RGB tactile images as PNG.

    .venv/bin/python examples/gripper.py --out out/gripper
    .venv/bin/python examples/gripper.py --physics coarse --resolution 32 24 --objects box

The sensors are evaluated once every ``--every`` physics steps (default 25: every 50 ms of
simulated time; MuJoCo's default 2 ms step), with sensors disabled in between, and every
``--png-every``-th evaluation is written: ``<object>_<frame>_<left|right>_<depth|rgb>.png``
(depth scaled so that white is 1.5 mm). For each object it prints how high the object rose
above where it rested and how much it sank during a 2 s hold.
"""

from __future__ import annotations

import argparse
import pathlib
import time

import mujoco
import numpy as np

import tacrom

HERE = pathlib.Path(__file__).resolve().parent
SENSORS = ("left_touch", "right_touch")
OPEN, CLOSED = 0.0, 0.035  # finger closing targets (m)
HIGH, LOW = 0.06, 0.0  # lift targets (m): above the objects, fingertips at working height
SLIDE = 0.03  # how far the held object is carried along y (m)


def load(physics: str, resolution: tuple[int, int], xml: pathlib.Path) -> mujoco.MjModel:
    spec = mujoco.MjSpec.from_file(str(xml))
    for sensor in spec.sensors:
        if sensor.name in SENSORS:
            config = dict(sensor.plugin.config)
            config.update(physics=physics, resolution=f"{resolution[0]} {resolution[1]}")
            config["outputs"] = "depth rgb"
            sensor.plugin.config = config
    return spec.compile()


class Run:
    """Drives the gripper through phases of linearly interpolated position targets and
    evaluates the sensors every ``every`` steps."""

    def __init__(self, model, out: pathlib.Path, every: int, png_every: int) -> None:
        self.m, self.d = model, mujoco.MjData(model)
        self.out, self.every, self.png_every = out, every, png_every
        self.frame = 0
        self.written = 0
        self.sensor_s = 0.0
        self.steps = 0
        self.name = ""
        self.track = None  # (body id, rest z, list of heights) while recording
        # ctrl: carry (y), lift (z), left and right finger closing.
        self.d.ctrl[:] = [0.0, HIGH, OPEN, OPEN]
        self.d.qpos[model.joint("lift").qposadr[0]] = HIGH
        mujoco.mj_forward(model, self.d)

    def move(self, seconds: float, carry=None, lift=None, close=None) -> None:
        m, d = self.m, self.d
        start = d.ctrl.copy()
        goal = start.copy()
        if carry is not None:
            goal[0] = carry
        if lift is not None:
            goal[1] = lift
        if close is not None:
            goal[2] = goal[3] = close
        n = int(round(seconds / m.opt.timestep))
        bit = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        for i in range(1, n + 1):
            d.ctrl[:] = start + (goal - start) * min(1.0, 2.0 * i / n)  # there by half time
            m.opt.disableflags |= bit
            mujoco.mj_step(m, d)
            m.opt.disableflags &= ~bit
            self.steps += 1
            if self.steps % self.every == 0:
                self.sense()

    def sense(self) -> None:
        t0 = time.perf_counter()
        mujoco.mj_forward(self.m, self.d)
        self.sensor_s += time.perf_counter() - t0
        if self.track is not None:
            body, rest, heights = self.track
            heights.append(self.d.xpos[body][2] - rest)
        if self.frame % self.png_every == 0:
            for sensor, side in zip(SENSORS, ("left", "right")):
                stem = self.out / f"{self.name}_{self.frame:04d}_{side}"
                tacrom.save_png(f"{stem}_depth.png", tacrom.depth(self.m, self.d, sensor), vmax=1.5e-3)
                tacrom.save_png(f"{stem}_rgb.png", tacrom.rgb(self.m, self.d, sensor))
                self.written += 2
        self.frame += 1

    def depth_max(self) -> tuple[float, float]:
        mujoco.mj_forward(self.m, self.d)
        return tuple(float(tacrom.depth(self.m, self.d, s).max()) for s in SENSORS)

    def pick(self, name: str) -> dict:
        m, d = self.m, self.d
        self.name = name
        body = m.body(name).id
        y = float(d.xpos[body][1])
        rest = float(d.xpos[body][2])
        self.move(0.5, carry=y, lift=HIGH, close=OPEN)
        self.move(0.5, lift=LOW)
        before = self.depth_max()
        self.move(0.5, close=CLOSED)
        grasp = self.depth_max()
        self.move(0.6, lift=HIGH)
        self.track = (body, rest, [])
        self.move(2.0)  # hold
        held = self.track[2]
        self.track = None
        lifted = float(d.xpos[body][2] - rest)
        self.move(0.8, carry=y + SLIDE)  # slide the held object along y
        carried = (float(d.xpos[body][1] - y), float(d.xpos[body][2] - rest))
        self.move(0.6, lift=LOW)
        self.move(0.4, close=OPEN)
        self.move(0.4, lift=HIGH)
        return {
            "depth_before_contact_mm": [v * 1e3 for v in before],
            "depth_grasped_mm": [v * 1e3 for v in grasp],
            "height_after_lift_mm": lifted * 1e3,
            "hold_2s_min_max_mm": (min(held) * 1e3, max(held) * 1e3),
            "carried_dy_dz_mm": (carried[0] * 1e3, carried[1] * 1e3),
            "placed_height_mm": float(d.xpos[body][2] - rest) * 1e3,
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("out/gripper"))
    parser.add_argument("--physics", default="rigid", choices=["rigid", "coarse", "rom"])
    parser.add_argument("--resolution", type=int, nargs=2, default=[64, 48], metavar=("W", "H"))
    parser.add_argument("--objects", nargs="+", default=["box", "cylinder", "hexagon"])
    parser.add_argument("--every", type=int, default=25, help="physics steps per sensor evaluation")
    parser.add_argument("--png-every", type=int, default=4, help="evaluations per written frame")
    parser.add_argument("--xml", type=pathlib.Path, default=HERE / "gripper.xml")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    run = Run(load(args.physics, tuple(args.resolution), args.xml), args.out, args.every, args.png_every)
    for name in args.objects:
        r = run.pick(name)
        lo, hi = r["hold_2s_min_max_mm"]
        print(
            f"{name:9s} depth before contact {r['depth_before_contact_mm'][0]:.2f} / "
            f"{r['depth_before_contact_mm'][1]:.2f} mm, grasped {r['depth_grasped_mm'][0]:.2f} / "
            f"{r['depth_grasped_mm'][1]:.2f} mm (left / right); lifted {r['height_after_lift_mm']:.1f} mm, "
            f"2 s hold {lo:.1f} to {hi:.1f} mm; slid {r['carried_dy_dz_mm'][0]:.1f} mm along y "
            f"at {r['carried_dy_dz_mm'][1]:.1f} mm; placed at {r['placed_height_mm']:.1f} mm",
            flush=True,
        )
    print(
        f"{args.physics} {args.resolution[0]}x{args.resolution[1]}: {run.steps} steps "
        f"({run.steps * run.m.opt.timestep:.1f} s simulated), {run.frame} sensor evaluations "
        f"of both fingers ({run.sensor_s:.2f} s), {run.written} PNGs in {args.out}; whole run "
        f"{time.perf_counter() - t0:.1f} s"
    )


if __name__ == "__main__":
    main()
