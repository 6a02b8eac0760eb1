"""Gymnasium environments with tactile observations.

``import tacrom`` registers them when Gymnasium is installed::

    import gymnasium as gym
    import tacrom

    env = gym.make("tacrom/GripperLift-v1", physics="rigid", tactile_rgb=True)

* ``tacrom/Press-v1`` (:class:`tacrom.envs.press.PressEnv`): press a sphere into a fixed
  sensor and slide it to a target spot, found by touch.
* ``tacrom/GripperLift-v1`` (:class:`tacrom.envs.gripper.GripperLiftEnv`): grasp and lift
  an object with a parallel-jaw gripper whose two fingertips carry tacrom sensors.
* ``tacrom/Press-v0``: the first press environment, :class:`tacrom.env.PressEnv`
  (observation: the depth image alone).

Observations are a ``Dict``: proprioception (``joint_pos``, ``joint_vel``, and
``gripper_opening`` for the gripper) and the tactile images, ``tactile_depth`` of shape
``(N, H, W)`` (float32, metres, one image per sensor, in a fixed order) and, when made with
``tactile_rgb=True``, ``tactile_rgb`` of shape ``(N, H, W, 3)`` (uint8). Every environment
takes ``physics`` (``"rigid"``, ``"coarse"``, ``"rom"``), ``resolution`` (W, H),
``tactile_rgb`` and ``render_mode`` (``"rgb_array"``); see docs/rl.md.
"""

from __future__ import annotations

__all__ = ["ENV_IDS", "register_envs"]

ENV_IDS = {
    "tacrom/Press-v0": ("tacrom.env:PressEnv", None),
    "tacrom/Press-v1": ("tacrom.envs.press:PressEnv", 50),
    "tacrom/GripperLift-v1": ("tacrom.envs.gripper:GripperLiftEnv", 100),
}


def register_envs() -> None:
    """Registers the environments of :data:`ENV_IDS` with Gymnasium (once; a later call
    leaves existing registrations alone)."""
    import gymnasium

    for env_id, (entry_point, max_steps) in ENV_IDS.items():
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(id=env_id, entry_point=entry_point, max_episode_steps=max_steps)
