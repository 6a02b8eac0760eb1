"""How the coupled grasp holds up at longer physics steps: ``tacrom/GripperLift-v1`` with both
fingertip gels pushing back (``coupling=True``, rom), the shortened grasp of the coupled
tests (descend 15 steps, close 10, lift 12) at each physics step asked for, the environment
step kept at 40 ms by ``frame_skip``, for every object and each seed. Prints a Markdown
table: per physics step, the grasps lifted (the episode's ``is_success`` at its end), those
with a step MuJoCo found unstable (its ``mjWARN_BADQACC`` count) and those with a
non-finite observation.

    .venv/bin/python examples/coupled_steps.py --steps 0.002 0.006 0.01 --seeds 5

What it showed (docs/rl.md, "A long physics step: the gel's force where it presses"): 15 of
15 grasps lifted at 2 to 6 ms, 13 at 8 ms and 9 at 10 ms (2 unstable).
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np

from tacrom.envs import gripper

#: Descend (15 steps), close (10), then lift (12): the coupled tests' grasp.
CYCLE = [(0.0, -1.0, -1.0)] * 15 + [(0.0, -1.0, 1.0)] * 10 + [(0.0, 0.5, 1.0)] * 12

#: The environment's step (s), kept whatever the physics step.
ENV_STEP = 0.04


def grasp(obj: str, seed: int, timestep: float) -> tuple[bool, bool, bool]:
    """Lifted, any step unstable, every observation finite."""
    env = gripper.GripperLiftEnv(
        physics="rom",
        object=obj,
        coupling=True,
        frame_skip=max(1, round(ENV_STEP / timestep)),
    )
    env.model.opt.timestep = timestep
    env.reset(seed=seed)
    finite = True
    for a in CYCLE:
        obs, _, _, _, info = env.step(np.array(a, dtype=np.float32))
        finite &= all(np.isfinite(v).all() for v in obs.values())
    unstable = env.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0
    env.close()
    return bool(info["is_success"]), unstable, finite


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=float, nargs="+", default=[0.002, 0.006, 0.01])
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()

    print("| physics step | grasps | lifted | unstable | not finite |")
    print("|---|---:|---:|---:|---:|")
    for timestep in args.steps:
        runs = [
            grasp(obj, seed, timestep) for obj in gripper.OBJECTS for seed in range(args.seeds)
        ]
        lifted = sum(r[0] for r in runs)
        unstable = sum(r[1] for r in runs)
        broken = sum(not r[2] for r in runs)
        print(
            f"| {timestep * 1e3:g} ms | {len(runs)} | {lifted} | {unstable} | {broken} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
