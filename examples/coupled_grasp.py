"""The tactile gripper with both fingertip gels pushing back (``tacrom/GripperLift-v1`` with
``coupling=True``): each pad's face lies on its gel's surface and stands for the gel in
MuJoCo's collision (``gel_geom``), so the grasp is carried by the gels' force, taken
implicitly in MuJoCo's constraint solve. Runs the grasp cycle's descent, close and lift
(50 environment steps of 20 physics steps of 2 ms) and prints, every fifth step, how far
the object rose, each gel's depth and squeeze, and the wall time of that step.

    .venv/bin/python examples/coupled_grasp.py --physics rom --object box

What it shows (docs/rl.md, "A coupled grasp"): every object is lifted on the gels alone,
at MuJoCo's 2 ms step, without a warning.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from tacrom.envs import gripper

#: Descend (15 steps), close (10), then lift (25).
CYCLE = [(0.0, -1.0, -1.0)] * 15 + [(0.0, -1.0, 1.0)] * 10 + [(0.0, 0.5, 1.0)] * 25


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--physics", default="rom", choices=["coarse", "rom"])
    parser.add_argument("--solver", help="the gels' solver (default: the physics' own)")
    parser.add_argument("--object", default="box", choices=list(gripper.OBJECTS))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    config = {"solver": args.solver} if args.solver else None
    env = gripper.GripperLiftEnv(
        physics=args.physics, object=args.object, coupling=True, sensor_config=config
    )
    env.reset(seed=args.seed)
    start = time.perf_counter()
    for step, a in enumerate(CYCLE, 1):
        t0 = time.perf_counter()
        obs, _, _, _, info = env.step(np.array(a, dtype=np.float32))
        if step % 5 == 0:
            gels = [
                f"{name} {1e3 * depth.max():.2f} mm, {force[2]:.2f} N"
                for name, depth, force in zip(("left", "right"), obs["tactile_depth"], info["gel_force"])
            ]
            print(
                f"step {step}: object {1e3 * info['object_height']:+.2f} mm; {'; '.join(gels)}; "
                f"success {info['is_success']}; this step {1e3 * (time.perf_counter() - t0):.0f} ms, "
                f"{time.perf_counter() - start:.1f} s so far"
            )


if __name__ == "__main__":
    main()
