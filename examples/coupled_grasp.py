"""The tactile gripper with both fingertip gels coupled (``coupling="on"``): the pads'
backing moved to the gels' base, so that MuJoCo's own contact only stops an object that
crushes a whole gel, and the grasp is left to the gels' push-back. Runs the grasp cycle's
close and lift (the first 35 steps of ``examples/rl_throughput.py``'s cycle, 20 physics
steps of 2 ms each) and prints, every fifth step, how far the object rose and each gel's
depth and normal force, with the wall time so far.

    .venv/bin/python examples/coupled_grasp.py --physics coarse --solver linear --object box

What it shows today (docs/rl.md, "A coupled grasp"): the explicit coupling cannot hold a
light object at MuJoCo's 2 ms step (the sensor warns that stiffness * timestep^2 / mass
exceeds 2), and the gels are solved at every physics step where no sensor runs.
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

import tacrom
from tacrom.envs import gripper
from tacrom.envs.base import configure_sensors

#: Close (10 steps), then lift (25), after 15 steps of descent with the fingers open.
CYCLE = [(0.0, -1.0, -1.0)] * 15 + [(0.0, -1.0, 1.0)] * 10 + [(0.0, 0.5, 1.0)] * 10


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--physics", default="coarse", choices=["coarse", "rom"])
    parser.add_argument("--solver", default="linear")
    parser.add_argument("--object", default="box", choices=list(gripper.OBJECTS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--implicit", action="store_true")
    args = parser.parse_args()

    spec = mujoco.MjSpec.from_file(str(gripper.asset_path("gripper.xml")))
    extra = {"coupling": "on", "solver": args.solver}
    if args.implicit:
        # Each pad's face on its gel's surface, standing for the gel in MuJoCo's collision
        # (its contacts carry the gel's push-back), and a backing at the gel's base.
        for name, finger, sign in (("left_pad", "left_finger", -1.0), ("right_pad", "right_finger", 1.0)):
            geom = spec.geom(name)
            geom.pos = [geom.pos[0] - sign * 0.0003, geom.pos[1], geom.pos[2]]
            backing = spec.body(finger).add_geom()
            backing.name = name + "_backing"
            backing.type = mujoco.mjtGeom.mjGEOM_BOX
            backing.size = [0.001, 0.015, 0.015]
            backing.pos = [sign * 0.005, 0.0, 0.0]
            backing.friction = geom.friction
            backing.condim = geom.condim
            backing.mass = 0.001
    else:
        # The backing's face from 0.3 mm below the gel's surface to its base (4 mm).
        for name, sign in (("left_pad", -1.0), ("right_pad", 1.0)):
            geom = spec.geom(name)
            geom.pos = [geom.pos[0] + sign * 0.0037, geom.pos[1], geom.pos[2]]
    configure_sensors(
        spec,
        gripper.SENSORS,
        physics=args.physics,
        resolution=(32, 24),
        outputs=["depth", "force"],
        extra=extra,
    )
    if args.implicit:
        for sensor, pad in zip(gripper.SENSORS, ("left_pad", "right_pad")):
            plugin = spec.sensor(sensor).plugin
            config = dict(plugin.config)
            config["gel_geom"] = pad
            plugin.config = config

    model = spec.compile()
    data = mujoco.MjData(model)
    # The episode's start as the environment draws it.
    env = gripper.GripperLiftEnv(physics="rigid", object=args.object)
    env.reset(seed=args.seed)
    data.qpos[:] = env.data.qpos
    data.ctrl[:] = env.data.ctrl
    mujoco.mj_forward(model, data)
    body = model.body(args.object).id
    z0 = data.xpos[body][2]
    start = time.perf_counter()
    for step, a in enumerate(CYCLE, 1):
        close = 0.5 * gripper.CLOSE_RANGE * (a[2] + 1.0)
        data.ctrl[:] = [gripper.CARRY_RANGE * a[0], 0.5 * gripper.LIFT_RANGE * (a[1] + 1.0), close, close]
        for _ in range(20):
            mujoco.mj_step(model, data)
        if step % 5 == 0:
            gels = []
            for name in gripper.SENSORS:
                out = tacrom.outputs(model, data, name)
                gels.append(f"{name} depth {1e3 * out['depth'].max():.2f} mm, force {out['force'][2]:.2f} N")
            rise = 1e3 * (data.xpos[body][2] - z0)
            print(f"step {step}: object {rise:+.2f} mm; {'; '.join(gels)}; {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
