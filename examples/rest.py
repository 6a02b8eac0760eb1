"""Drops a 20 g ball on a gel that pushes back (examples/rest.xml, coupling="on") and
prints how it settles: depth, the gel's force against the ball's weight, and speed.

    python examples/rest.py [--physics coarse|rom|fine] [--seconds 0.3]
"""

import argparse
import pathlib
import time

import mujoco

import tacrom

HERE = pathlib.Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--physics", default="coarse")
    ap.add_argument("--seconds", type=float, default=0.3)
    args = ap.parse_args()
    xml = (HERE / "rest.xml").read_text()
    xml = xml.replace('<config key="physics" value="coarse"/>', f'<config key="physics" value="{args.physics}"/>')
    if args.physics == "rom":
        # The shipped model is trained for the default friction.
        xml = xml.replace('<config key="friction" value="0"/>', "")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    ball = model.body("ball")
    weight = float(ball.mass[0]) * -model.opt.gravity[2]
    radius = float(model.geom("ball").size[0])
    steps = int(round(args.seconds / model.opt.timestep))
    start = time.perf_counter()
    print(f"{'t (s)':>6} {'depth (mm)':>10} {'gel force (N)':>13} {'speed (mm/s)':>12}")
    for k in range(1, steps + 1):
        mujoco.mj_step(model, data)
        if k % (steps // 10) == 0:
            force = tacrom.outputs(model, data, "touch")["force"][2]
            depth = (radius - data.qpos[2]) * 1e3
            print(f"{data.time:6.3f} {depth:10.4f} {force:13.5f} {abs(data.qvel[2]) * 1e3:12.4f}")
    elapsed = time.perf_counter() - start
    print(f"weight {weight:.5f} N; {steps} steps in {elapsed:.2f} s ({elapsed / steps * 1e3:.1f} ms per step)")


if __name__ == "__main__":
    main()
