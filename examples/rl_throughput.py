"""Environment steps per second of the tactile Gymnasium environments, per physics mode, in
one process and in two (``gymnasium.vector.AsyncVectorEnv``), printed as a Markdown table.

    .venv/bin/python examples/rl_throughput.py
    .venv/bin/python examples/rl_throughput.py --envs tacrom/Press-v1 --physics rigid --procs 1

The actions are scripted so that the sensors are in contact for most steps, as in a task
being learned, not idle: Press-v1 presses 0.5 to 1 mm deep at a new random spot every step
(``--policy random``, an untrained policy: the gel starts each solve far from the last) or
sweeps along x and back every 40 steps, 0.5 to 1 mm deep (``--policy sweep``, a smooth
one);
GripperLift-v1 runs 100-step episodes of descend (15 steps), close (10), lift (15), hold
(40), put down (10), open (10), the sensors touching the object for about 70 of them. Each
measurement follows a warm-up episode start and counts environment steps (with two
processes, both processes' steps) over wall time, and for one process also the CPU time
per step (what the machine's other jobs do not inflate); episode resets are included. The two
worker processes start from a forkserver (see docs/rl.md).
"""

from __future__ import annotations

import argparse
import functools
import time

import gymnasium as gym
import numpy as np

import tacrom  # noqa: F401  (registers the environments)
from modes import mode_config

GRIPPER_CYCLE = (
    [(0.0, -1.0, -1.0)] * 15
    + [(0.0, -1.0, 1.0)] * 10
    + [(0.0, 0.5, 1.0)] * 55
    + [(0.0, -1.0, 1.0)] * 10
    + [(0.0, -1.0, -1.0)] * 10
)


def action(env_id: str, step: int, rng: np.random.Generator, policy: str) -> np.ndarray:
    if env_id.startswith("tacrom/GripperLift"):
        return np.array(GRIPPER_CYCLE[step % len(GRIPPER_CYCLE)], np.float32)
    if policy == "sweep":
        phase = 2 * np.pi * step / 40
        return np.array([np.sin(phase), 0.5 + 0.5 * np.sin(phase / 3)], np.float32)
    return np.array([rng.uniform(-1, 1), rng.uniform(0, 1)], np.float32)


def make(
    env_id: str,
    physics: str,
    resolution,
    threads: int = 1,
    coupling: bool = False,
    servo_time: float | None = None,
    extra: dict | None = None,
):
    """A picklable maker of the environment: ``tacrom.envs:`` in the id makes Gymnasium
    import (and so register) tacrom in a fresh worker process. After a dash, a solver's
    name names the gel's solver (``coarse-linear``: the coarse gel with
    ``solver="linear"``), anything else rom's shipped model (``rom-default``:
    ``model="rom-default"``, rom on the relaxation as it was before the linear gel);
    ``threads`` the sensors' own threads; ``coupling`` GripperLift-v1's gels pushing back
    (its ``coupling=True``; other environments and ``rigid`` ignore it); ``servo_time``
    GripperLift-v1's ``servo_time`` (None: its default); ``extra`` further sensor
    attributes (``{"hold": "1e-6"}``), given as the environments' ``sensor_config``."""
    config = {"threads": threads} if threads != 1 else {}
    config.update(mode_config(physics))
    config.update(extra or {})
    physics = config.pop("physics")
    kwargs = {"physics": physics, "sensor_config": config} if config else {"physics": physics}
    if resolution:
        kwargs["resolution"] = tuple(resolution)
    if coupling and env_id.startswith("tacrom/GripperLift") and physics != "rigid":
        kwargs["coupling"] = True
    if servo_time is not None and env_id.startswith("tacrom/GripperLift"):
        kwargs["servo_time"] = servo_time
    return functools.partial(gym.make, f"tacrom.envs:{env_id}", **kwargs)


def measure(
    env_id: str,
    physics: str,
    procs: int,
    steps: int,
    resolution,
    policy: str,
    threads: int = 1,
    coupling: bool = False,
    servo_time: float | None = None,
    extra: dict | None = None,
) -> tuple[float, float | None]:
    """Environment steps per second of wall time over ``steps`` steps of each process, and
    (one process only) CPU milliseconds per step, which other jobs on the machine do not
    inflate."""
    rng = np.random.default_rng(0)
    if procs == 1:
        env = make(env_id, physics, resolution, threads, coupling, servo_time, extra)()
        env.reset(seed=0)
        t0, c0 = time.perf_counter(), time.process_time()
        for i in range(steps):
            _, _, terminated, truncated, _ = env.step(action(env_id, i, rng, policy))
            if terminated or truncated:
                env.reset()
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
        env.close()
        return steps / elapsed, 1e3 * cpu / steps
    # Workers start from a fresh forkserver, not by forking this process: a process forked
    # after a gel sensor (coarse, rom) ran here would hang in the plugin's thread pool.
    envs = gym.vector.AsyncVectorEnv(
        [make(env_id, physics, resolution, threads, coupling, servo_time, extra)] * procs,
        context="forkserver",
    )
    try:
        envs.reset(seed=0)
        t0 = time.perf_counter()
        for i in range(steps):
            envs.step(np.stack([action(env_id, i, rng, policy) for _ in range(procs)]))
        elapsed = time.perf_counter() - t0
    finally:
        envs.close()
    return steps * procs / elapsed, None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["tacrom/Press-v1", "tacrom/GripperLift-v1"])
    parser.add_argument(
        "--physics",
        nargs="+",
        default=["rigid", "coarse", "rom"],
        help="modes: rigid, coarse, rom, fine, MODE-SOLVER (coarse-linear: coarse with "
        "solver=linear) or rom-MODEL (rom-default: rom with model=rom-default)",
    )
    parser.add_argument("--procs", nargs="+", type=int, default=[1, 2])
    parser.add_argument(
        "--steps",
        type=int,
        nargs=2,
        default=[1000, 100],
        metavar=("RIGID", "GEL"),
        help="environment steps per process: rigid, then coarse and rom",
    )
    parser.add_argument(
        "--resolution", type=int, nargs=2, metavar=("W", "H"), help="default: each env's own"
    )
    parser.add_argument("--policy", default="random", choices=["random", "sweep"])
    parser.add_argument(
        "--threads", type=int, default=1, help="each sensor's threads (its `threads` attribute)"
    )
    parser.add_argument(
        "--coupling",
        action="store_true",
        help="GripperLift-v1 with both gels pushing back (coupling=True): the gels carry the grasp",
    )
    parser.add_argument(
        "--servo-time",
        type=float,
        help="GripperLift-v1's servo_time (s; 0: the arm's servos unfiltered; default: its own)",
    )
    parser.add_argument(
        "--config",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="further attributes of the gel sensors (hold=1e-6: the sensor's own default hold "
        "in GripperLift-v1, whose own is 5e-6)",
    )
    args = parser.parse_args()
    extra = {}
    for item in args.config:
        key, sep, value = item.partition("=")
        if not (key and sep):
            parser.error(f"--config takes KEY=VALUE, not {item!r}")
        extra[key] = value
    shown = "".join(f", {k}={v}" for k, v in extra.items())
    print("| environment | policy | physics | processes | steps/s | ms/step | CPU ms/step |")
    print("|---|---|---|---:|---:|---:|---:|")
    for env_id in args.envs:
        for physics in args.physics:
            steps = args.steps[0] if physics == "rigid" else args.steps[1]
            for procs in args.procs:
                rate, cpu = measure(
                    env_id,
                    physics,
                    procs,
                    steps,
                    args.resolution,
                    args.policy,
                    args.threads,
                    args.coupling,
                    args.servo_time,
                    extra if physics != "rigid" else None,
                )
                policy = "grasp cycle" if env_id.startswith("tacrom/GripperLift") else args.policy
                if args.coupling and policy == "grasp cycle" and physics != "rigid":
                    policy += ", coupled"
                print(
                    f"| {env_id} | {policy} | {physics}{shown if physics != 'rigid' else ''} | "
                    f"{procs} | {rate:.1f} | "
                    f"{1e3 / rate:.1f} | {'-' if cpu is None else f'{cpu:.1f}'} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
