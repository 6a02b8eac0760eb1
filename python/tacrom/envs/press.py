"""``tacrom/Press-v1``: press a sphere into a fixed tactile sensor and slide it to a target
spot, found by touch."""

from __future__ import annotations

from typing import Any, Optional

import gymnasium as gym
import mujoco
import numpy as np

import tacrom
from tacrom.envs.base import TactileEnv, configure_sensors

#: The press scene: a sphere (R = 5 mm) on two slide joints ("x" along the gel, "press"
#: into it) over a fixed sensor; the position actuators take targets in metres.
SCENE = """
<mujoco model="tacrom press env">
  <extension><plugin plugin="tacrom.tactile"/></extension>
  <option timestep="0.002" gravity="0 0 0"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <worldbody>
    <light pos="0 -0.05 0.1" dir="0 0.5 -1"/>
    <camera name="side" pos="0 -0.06 0.025" xyaxes="1 0 0 0 0.4 1"/>
    <body name="sensor">
      <geom name="gel" type="box" size="0.015 0.015 0.002" pos="0 0 -0.002"
            rgba="0.85 0.85 0.8 1" contype="0" conaffinity="0"/>
      <geom name="pad" type="box" size="0.015 0.015 0.002" pos="0 0 -0.006"
            rgba="0.3 0.3 0.3 1" contype="0" conaffinity="0"/>
      <site name="gel"/>
    </body>
    <body name="indenter" pos="0 0 0.005">
      <joint name="x" type="slide" axis="1 0 0" range="-0.006 0.006" damping="2"/>
      <joint name="press" type="slide" axis="0 0 -1" range="-0.002 0.002" damping="5"/>
      <geom type="sphere" size="0.005" mass="0.01" contype="0" conaffinity="0"
            rgba="0.8 0.2 0.2 1"/>
    </body>
  </worldbody>
  <actuator>
    <position joint="x" kp="2000" ctrlrange="-0.005 0.005"/>
    <position joint="press" kp="2000" ctrlrange="0 0.001"/>
  </actuator>
  <sensor>
    <plugin name="touch" plugin="tacrom.tactile" objtype="site" objname="gel">
      <config key="physics" value="rigid"/>
    </plugin>
  </sensor>
</mujoco>
"""

#: Half the slide range of the action (m) and the deepest press target (m).
X_RANGE = 0.005
MAX_PRESS = 0.001


def press_model(
    physics: Optional[str], resolution: tuple[int, int], outputs=("depth",), sensor_config=None
) -> tuple[mujoco.MjModel, float]:
    """The press scene compiled with its sensor ``touch`` configured; returns the model and
    the gel's thickness (m)."""
    spec = mujoco.MjSpec.from_string(SCENE)
    thickness = configure_sensors(
        spec,
        ["touch"],
        physics=physics,
        resolution=resolution,
        outputs=outputs,
        extra=sensor_config,
    )
    return spec.compile(), thickness


class PressEnv(TactileEnv):
    """Press a sphere (radius 5 mm) into the gel and slide it along x to ``target_x``.

    Action ``Box(-1, 1, (2,))``: ``[x, press]`` targets, ``x = 5 mm * a[0]`` along the gel,
    ``press = 0.5 mm * (a[1] + 1)`` into it (0 to 1 mm). One step: ``frame_skip`` physics
    steps of 2 ms (default 25: 50 ms), then one sensor evaluation.

    Observation ``Dict``:

    * ``joint_pos`` ``(2,)`` float32: the sphere's slide ``x`` and press depth (m), clipped
      to +-10 mm;
    * ``joint_vel`` ``(2,)`` float32: their velocities (m/s), clipped to +-1 m/s;
    * ``tactile_depth`` ``(1, H, W)`` float32: the depth image (m, positive into the gel,
      within [0, T]);
    * ``tactile_rgb`` ``(1, H, W, 3)`` uint8: the RGB tactile image, with
      ``tactile_rgb=True``.

    Reward: minus the squared distance (mm^2) of the contact's centroid from ``target_x``,
    -25 without contact (a toy task: find a spot by touch). ``info["centroid_x"]``: the
    centroid (m), NaN without contact. Episodes end by the time limit (50 steps when made
    with ``gymnasium.make``).

    ``physics``: the sensor's default, ``"rom"`` (on the linear gel, about 4 ms a step), or
    ``"rigid"`` (no gel, a fraction of a millisecond) or ``"coarse"``. ``sensor``: a sensor
    file or a shipped sensor's name (``"gelsight-mini"``): its gel, camera and optics, and
    its physics unless ``physics`` is given. ``sensor_config``: further attributes of the
    sensor (``{"tolerance": "1e-2"}``; docs/configuration.md).
    """

    def __init__(
        self,
        physics: Optional[str] = None,
        resolution: tuple[int, int] = (64, 48),
        tactile_rgb: bool = False,
        render_mode: Optional[str] = None,
        target_x: float = 0.002,
        frame_skip: int = 25,
        render_size: tuple[int, int] = (320, 240),
        sensor_config: Optional[dict] = None,
        sensor: Optional[str] = None,
    ) -> None:
        outputs = ["depth", "rgb"] if tactile_rgb else ["depth"]
        config = dict(sensor_config or {})
        if sensor is not None:
            config["sensor"] = sensor
        elif physics is None:
            physics = "rom"
        model, thickness = press_model(physics, resolution, outputs, config)
        super().__init__(
            model,
            ["touch"],
            gel_thickness=thickness,
            frame_skip=frame_skip,
            tactile_rgb=tactile_rgb,
            render_mode=render_mode,
            render_size=render_size,
            camera="side",
        )
        self.physics = physics or tacrom.attribute(config, "physics")
        self.target_x = float(target_x)
        self._fov_x = float(tacrom.attribute(config, "fov").split()[0])
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.observation_space = gym.spaces.Dict(
            {
                "joint_pos": gym.spaces.Box(-0.01, 0.01, shape=(2,), dtype=np.float32),
                "joint_vel": gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32),
                **self._tactile_spaces(),
            }
        )

    def _observe(self) -> dict:
        d = self.data
        return {
            "joint_pos": np.clip(d.qpos[:2], -0.01, 0.01).astype(np.float32),
            "joint_vel": np.clip(d.qvel[:2], -1.0, 1.0).astype(np.float32),
            **self._tactile_obs(),
        }

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[0] = self.np_random.uniform(-0.004, 0.004)
        self.data.ctrl[:] = [self.data.qpos[0], 0.0]
        mujoco.mj_forward(self.model, self.data)
        return self._observe(), {}

    def step(self, action) -> tuple[dict, float, bool, bool, dict[str, Any]]:
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        self.data.ctrl[:] = [X_RANGE * a[0], 0.5 * MAX_PRESS * (a[1] + 1.0)]
        self._simulate()
        obs = self._observe()
        depth = obs["tactile_depth"][0].astype(np.float64)
        total = float(depth.sum())
        if total > 0:
            w = depth.shape[1]
            cols = (np.arange(w) + 0.5) / w * self._fov_x - self._fov_x / 2
            centroid = float((depth.sum(axis=0) * cols).sum() / total)
            reward = -(((centroid - self.target_x) * 1e3) ** 2)
        else:
            centroid, reward = float("nan"), -25.0
        return obs, reward, False, False, {"centroid_x": centroid}
