"""How the coupled grasp holds up at longer physics steps: ``tacrom/GripperLift-v1`` with both
fingertip gels pushing back (``coupling=True``, rom), the shortened grasp of the coupled
tests (descend 15 steps, close 10, lift 12) and then 15 more steps of the lift's action
(the object held up), at each physics step asked for, the environment step kept at 40 ms
by ``frame_skip``, for every object and each seed. Prints a Markdown table: per physics
step, the grasps lifted (``is_success`` at the lift's 12th step, as the coupled tests ask),
those whose hold was quiet (over the last 10 held steps the object moved less than
:data:`QUIET` against the left finger a step: a held object comes to rest), the largest
squeeze of a gel over those steps (N; a quiet hold squeezes 3.5 to 6 N), those with a step
MuJoCo found unstable (its ``mjWARN_BADQACC`` count) and those with a non-finite
observation.

    .venv/bin/python examples/coupled_steps.py --steps 0.002 0.006 0.01 0.0133 --seeds 5

What it showed (docs/rl.md, "A long physics step: the fingers' damping, taken after the
solve"), with the fingers' drives' inertia on their joints (``examples/gripper.xml``): 15
of 15 grasps lifted and held still at 2 to 10 ms; at 13.3 ms 13 holds still, at 20 ms 13
lifted and none still. Before it ("A long physics step: a hold that bounces"): 15 lifted
at 2 to 6 ms, 13 at 8 ms and 9 at 10 ms (2 unstable); 15 holds still at 2 and 4 ms, 14
at 6 ms, 7 at 8 ms and none at 10 ms, the gels bouncing the object by millimetres at up
to 100 N and more.
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np

from tacrom.envs import gripper

#: Descend (15 steps), close (10), then lift (12): the coupled tests' grasp.
CYCLE = [(0.0, -1.0, -1.0)] * 15 + [(0.0, -1.0, 1.0)] * 10 + [(0.0, 0.5, 1.0)] * 12

#: Steps held after the grasp (the lift's action kept), and those of them measured.
HOLD, MEASURED = 15, 10

#: The most a quietly held object moves against the left finger in an environment step (m).
QUIET = 10e-6

#: The environment's step (s), kept whatever the physics step.
ENV_STEP = 0.04


def grasp(obj: str, seed: int, timestep: float) -> tuple[bool, bool, float, bool, bool]:
    """Lifted, the hold quiet, the largest squeeze of a gel in the hold (N), any step
    unstable, every observation finite."""
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
    lifted = bool(info["is_success"])
    m, d = env.model, env.data
    finger, body = m.body("left_finger").id, m.body(obj).id
    where, squeeze = [], 0.0
    for k in range(HOLD):
        obs, _, _, _, info = env.step(np.array(CYCLE[-1], dtype=np.float32))
        finite &= all(np.isfinite(v).all() for v in obs.values())
        if k >= HOLD - MEASURED:
            turn = d.xmat[finger].reshape(3, 3)
            where.append(turn.T @ (d.xpos[body] - d.xpos[finger]))
            squeeze = max(squeeze, float(np.max(info["gel_force"][:, 2])))
    moved = np.abs(np.diff(np.array(where), axis=0)).max()
    unstable = d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0
    env.close()
    return lifted, bool(moved < QUIET), squeeze, unstable, finite


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=float, nargs="+", default=[0.002, 0.006, 0.01])
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()

    print(
        "| physics step | grasps | lifted | quiet hold | largest squeeze in the hold | "
        "unstable | not finite |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for timestep in args.steps:
        runs = [
            grasp(obj, seed, timestep) for obj in gripper.OBJECTS for seed in range(args.seeds)
        ]
        lifted = sum(r[0] for r in runs)
        quiet = sum(r[1] for r in runs)
        squeeze = max(r[2] for r in runs)
        unstable = sum(r[3] for r in runs)
        broken = sum(not r[4] for r in runs)
        print(
            f"| {timestep * 1e3:g} ms | {len(runs)} | {lifted} | {quiet} | {squeeze:.1f} N | "
            f"{unstable} | {broken} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
