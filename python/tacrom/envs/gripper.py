"""``tacrom/GripperLift-v1``: grasp and lift an object with a parallel-jaw gripper whose two
fingertips carry tacrom sensors (the scene of ``examples/gripper.xml``)."""

from __future__ import annotations

import warnings
from typing import Any, Optional, Sequence

import gymnasium as gym
import mujoco
import numpy as np

import tacrom
from tacrom.envs.base import TactileEnv, asset_path, configure_sensors

#: The objects of the scene (body names), the one to lift chosen per episode.
OBJECTS = ("box", "cylinder", "hexagon")
#: Where the objects not in play wait, out of the gripper's reach (x, y on the table).
PARKING = ((0.2, -0.1), (0.2, 0.0), (0.2, 0.1))
#: The actuated joints, in ``joint_pos`` order.
JOINTS = ("carry", "lift", "left", "right")
SENSORS = ("left_touch", "right_touch")

#: Action scaling: the carry (y) target within +-CARRY_RANGE around the object, the lift
#: (z) target within [0, LIFT_RANGE], the fingers' closing target within [0, CLOSE_RANGE].
CARRY_RANGE = 0.02
LIFT_RANGE = 0.08
CLOSE_RANGE = 0.035
#: The pads' faces are this far apart with the fingers open (joint positions 0).
OPEN_GAP = 0.07
#: The gripper's height at reset (lift joint, m): the fingertips 50 mm higher than at the
#: bottom of the lift range, above every object.
START_LIFT = 0.05
#: The arm's servos (carry and lift) follow their targets through a first-order filter of
#: this time constant (s; MuJoCo's ``filterexact`` actuator dynamics), as an arm's
#: trajectory generator does: a jump of the lift's target from the table to 60 mm up no
#: longer takes the gripper to 1.1 m/s at up to 12.5 g (passed on to the object through
#: the grasp's friction alone), but to 0.35 m/s at up to 1.0 g. The fingers' own force
#: limit already bounds their speed. ``servo_time=0`` drives the targets unfiltered.
SERVO_TIME = 0.1
#: The filtered actuators.
FILTERED = ("carry", "lift")
#: The longest physics step (s) at which the coupled grasp was measured to hold the lifted
#: object still (docs/rl.md, "A long physics step: the fingers' damping, taken after the
#: solve": 15 of 15 grasps at 2 to 10 ms, 13 at 13.3 ms, none at 20 ms, where the gels
#: bounce the object between the fingers by millimetres at up to 126 N). A coupled episode
#: reset at a longer step warns.
COUPLED_STEP_LIMIT = 0.01
#: The sensors' ``hold`` (m) unless ``sensor_config`` gives one: a frame is the last
#: solve's again while every object moved less than this against the gel since (scaled
#: down below 0.5 mm of depth). The sensor's own default, 1 um, holds a frame to about
#: the solve's tolerance; a grasp that creeps and settles by microns re-solves both gels
#: at nearly every step at that. 5 um: a quarter less CPU over the coupled grasp cycle,
#: the depth images within 0.25 um on average and 3.9 um at the 99th percentile of those
#: solved at every frame, the lifted object within 2.4 um of its height (docs/rl.md, "A
#: looser hold").
GRASP_HOLD = 5e-6


#: Each fingertip's pad geom, the finger body it hangs on and the side its gel faces.
PADS = (("left_pad", "left_finger", 1.0), ("right_pad", "right_finger", -1.0))
#: How far each pad's collision face lies below its gel's free surface, as a fraction of
#: the gel's thickness (0.3 mm of the default 4 mm gel): a held object indents the gel by
#: that and MuJoCo's own penetration.
PAD_SINK = 0.075


def fit_pads(spec: mujoco.MjSpec, sensors: Sequence[str] = SENSORS) -> None:
    """Fits each fingertip's pad to its sensor's gel as configured in ``spec``: its face the
    gel's face (the gel's ``size`` along the site's x and y: the finger's y and z) and
    :data:`PAD_SINK` of the gel's thickness below its surface. The scene's pads are its
    GelSight Minis'; the default gel's are 30 x 30 mm, 0.3 mm below."""
    found = {s.name: s for s in spec.sensors}
    for sensor, (pad, _, side) in zip(sensors, PADS):
        size = tacrom.attribute(dict(found[sensor].plugin.config), "size")
        lx, ly, thickness = (float(v) for v in size.split())
        geom = spec.geom(pad)
        half = float(geom.size[0])
        geom.size = [half, 0.5 * lx, 0.5 * ly]
        geom.pos = [-side * (half + PAD_SINK * thickness), geom.pos[1], geom.pos[2]]


def couple_pads(spec: mujoco.MjSpec, sensors: Sequence[str] = SENSORS) -> None:
    """Makes both fingertip gels push back (``coupling="on"``) through MuJoCo's contact:
    each pad's face moves onto its gel's surface and becomes the gel's geom (``gel_geom``),
    whose contacts with the objects carry the gel's force, taken implicitly in MuJoCo's
    constraint solve, without MuJoCo's torsional friction (the pad's ``condim`` 3, its
    priority above the objects'); a thin backing at the gel's base (4 mm deeper) stops an
    object that crushes the whole gel. Call after :func:`configure_sensors` has chosen a
    gel physics."""
    found = {s.name: s for s in spec.sensors}
    for sensor, (pad, finger, side) in zip(sensors, PADS):
        geom = spec.geom(pad)
        half = float(geom.size[0])
        # The pad's face onto the gel's surface (the site's origin, x = 0 in the finger).
        geom.pos = [-side * half, geom.pos[1], geom.pos[2]]
        # Its contacts without MuJoCo's torsional friction (condim 3, and a priority above
        # the objects' so that its condim is the pair's): the gel resists a turn about its
        # normal through its contact points' tangential rows, and the soft torsional row
        # beside them let a held object creep round for seconds.
        geom.condim = 3
        geom.priority = 1
        plugin = found[sensor].plugin
        config = dict(plugin.config)
        thickness = float(tacrom.attribute(config, "size").split()[2])
        backing = spec.body(finger).add_geom()
        backing.name = f"{pad}_backing"
        backing.type = mujoco.mjtGeom.mjGEOM_BOX
        backing.size = [0.0005, geom.size[1], geom.size[2]]
        backing.pos = [-side * (thickness + 0.0005), geom.pos[1], geom.pos[2]]
        backing.condim = geom.condim
        backing.friction = geom.friction
        backing.mass = 0.001
        backing.rgba = [0.35, 0.37, 0.4, 1.0]
        config.update(coupling="on", gel_geom=pad)
        plugin.config = config
    # The gels carry the pads' friction now: MuJoCo's no-slip pass, which would make the
    # pads' contacts stick rigidly, is the scene's for its rigid pads only.
    spec.option.noslip_iterations = 0


def filter_servos(spec: mujoco.MjSpec, seconds: float, names: Sequence[str] = FILTERED) -> None:
    """Makes the position servos ``names`` follow their targets through a first-order
    filter of time constant ``seconds`` (s; MuJoCo's ``filterexact`` dynamics, each with one
    activation, the filtered target); ``seconds=0`` leaves them unfiltered."""
    if not (seconds >= 0.0 and np.isfinite(seconds)):
        raise ValueError(f"servo_time must be a finite time of at least 0 s, not {seconds!r}")
    if seconds == 0.0:
        return
    for name in names:
        actuator = spec.actuator(name)
        actuator.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
        actuator.dynprm[0] = seconds
        actuator.actdim = 1


class GripperLiftEnv(TactileEnv):
    """Grasp an object on the table and lift it, with a tactile sensor in each fingertip.

    The scene is ``examples/gripper.xml`` (shipped in the package as
    ``tacrom/envs/assets/gripper.xml``): a gripper on a carry (y) and a lift (z) slide with
    two fingers closing along x, a tactile gel on each fingertip (the scene's GelSight Minis
    when ``sensor="gelsight-mini"``, else the default 30 x 30 x 4 mm gel), and three objects
    (box 24 x 16 x 40 mm, cylinder R = 12 mm x 40 mm, the ``hexagon`` mesh); one is placed
    under the gripper per episode (``object``: one name, or ``"random"``), 0 to 4 mm off
    centre along y and turned up to 0.15 rad about z, the others parked out of reach.

    Action ``Box(-1, 1, (3,))``: position targets, ``carry = 20 mm * a[0]`` (y),
    ``lift = 40 mm * (a[1] + 1)`` (z, 0 at the bottom: fingertip centres 17 mm above the
    table), ``close = 17.5 mm * (a[2] + 1)`` (each finger's closing travel; 0 open, 35 mm
    closed, squeezing with 300 N/m times the remaining travel, at most 8 N). One step:
    ``frame_skip`` physics steps of 2 ms (default 20: 40 ms), then one sensor evaluation.

    Observation ``Dict``:

    * ``joint_pos`` ``(4,)`` float32: carry, lift, left and right finger (m), clipped to
      +-0.2 m;
    * ``joint_vel`` ``(4,)`` float32: their velocities (m/s), clipped to +-10 m/s;
    * ``gripper_opening`` ``(1,)`` float32: the distance between the two pads (m), 0 to
      70 mm;
    * ``tactile_depth`` ``(2, H, W)`` float32: depth images (m, within [0, T]) of the left
      (index 0, at -x) and the right (index 1) fingertip, each seen from the object: row 0
      at the top of the pad, columns along the pad's width;
    * ``tactile_rgb`` ``(2, H, W, 3)`` uint8: their RGB tactile images, with
      ``tactile_rgb=True``.

    Reward: ``0.25`` per fingertip in contact (any depth pixel above zero) plus
    ``min(height / lift_target, 1)``, ``height`` being how far the object is above where it
    rested (m). ``info``: ``object``, ``object_height``, ``contacts`` (fingertips in
    contact) and ``is_success`` (both in contact and the object at least ``lift_target``
    up). Episodes end by the time limit (100 steps, 4 s, when made with ``gymnasium.make``).

    ``physics``: the sensor's default, ``"rom"`` (on the linear gel, about 18 ms a step over
    the grasp cycle, docs/rl.md), or ``"rigid"`` (no gel, under a millisecond) or
    ``"coarse"``. ``sensor``: a sensor file or a shipped sensor's name for both fingertips
    (``"gelsight-mini"``: its gel, window and optics, as the scene's own fingertips, and its
    physics unless ``physics`` is given);
    without one, the default 30 x 30 x 4 mm gel, on which the grasp was designed. Each pad
    is fitted to its gel (:func:`fit_pads`). ``sensor_config``: further attributes of both sensors
    (``{"tolerance": "1e-2"}``, ``{"threads": 2}``; docs/configuration.md); their ``hold``
    is :data:`GRASP_HOLD` (5 um) unless given here (``{"hold": "1e-6"}``: the sensor's
    own default) or by the sensor file.
    ``coupling``: the gels push back and hold the object (:func:`couple_pads`; needs
    ``"coarse"`` or ``"rom"``): the grasp is carried by the gels, not by a rigid pad;
    ``info["gel_force"]`` ``(2, 3)``: each gel's force on the object (N, in its sensor's
    frame: ``[..., 2]`` the squeeze); at a physics step beyond :data:`COUPLED_STEP_LIMIT`
    (10 ms) a reset warns that the hold may bounce. ``servo_time``: the time constant (s) of
    the filter through which the carry and lift servos follow their targets
    (:data:`SERVO_TIME`; 0: none, the targets taken at once).
    """

    def __init__(
        self,
        physics: Optional[str] = None,
        resolution: tuple[int, int] = (32, 24),
        tactile_rgb: bool = False,
        render_mode: Optional[str] = None,
        object: str = "random",
        lift_target: float = 0.04,
        frame_skip: int = 20,
        render_size: tuple[int, int] = (320, 240),
        sensor_config: Optional[dict] = None,
        sensor: Optional[str] = None,
        coupling: bool = False,
        servo_time: float = SERVO_TIME,
    ) -> None:
        if object != "random" and object not in OBJECTS:
            raise ValueError(f"object must be 'random' or one of {OBJECTS}, not {object!r}")
        if physics is None and sensor is None and "sensor" not in (sensor_config or {}):
            physics = "rom"
        if coupling and physics == "rigid":
            raise ValueError("coupling needs a gel physics ('coarse' or 'rom'), not 'rigid'")
        spec = mujoco.MjSpec.from_file(str(asset_path("gripper.xml")))
        extra = {**(sensor_config or {}), **({"sensor": sensor} if sensor else {})}
        if "hold" not in extra and not (
            extra.get("sensor") and "hold" in tacrom.sensor_file(str(extra["sensor"]))
        ):
            # (A sensor file's own `hold` stands.)
            extra["hold"] = GRASP_HOLD
        if "sensor" not in extra:
            # The scene's fingertips are GelSight Minis; the environment's default is the
            # default gel, on which its costs and its coupled grasp are measured.
            for s in spec.sensors:
                if s.name in SENSORS:
                    config = dict(s.plugin.config)
                    config.pop("sensor", None)
                    s.plugin.config = config
        outputs = ["depth", "rgb"] if tactile_rgb else ["depth"]
        if coupling:
            # How hard each gel squeezes, for info["gel_force"].
            outputs.append("force")
        thickness = configure_sensors(
            spec,
            SENSORS,
            physics=physics,
            resolution=resolution,
            outputs=outputs,
            extra=extra,
        )
        fit_pads(spec)
        if coupling:
            couple_pads(spec)
        filter_servos(spec, servo_time)
        super().__init__(
            spec.compile(),
            SENSORS,
            gel_thickness=thickness,
            frame_skip=frame_skip,
            tactile_rgb=tactile_rgb,
            render_mode=render_mode,
            render_size=render_size,
            camera="overview",
        )
        m = self.model
        left = next(s for s in spec.sensors if s.name == SENSORS[0])
        self.physics = physics or tacrom.attribute(dict(left.plugin.config), "physics")
        self.coupling = bool(coupling)
        self.object_choice = object
        self.lift_target = float(lift_target)
        self._qpos = np.array([m.joint(j).qposadr[0] for j in JOINTS])
        self._dof = np.array([m.joint(j).dofadr[0] for j in JOINTS])
        self._bodies = {name: m.body(name).id for name in OBJECTS}
        self._free = {name: m.joint(name).qposadr[0] for name in OBJECTS}
        self._rest_z = {name: float(m.qpos0[self._free[name] + 2]) for name in OBJECTS}
        self.object = OBJECTS[0]

        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self.observation_space = gym.spaces.Dict(
            {
                "joint_pos": gym.spaces.Box(-0.2, 0.2, shape=(4,), dtype=np.float32),
                "joint_vel": gym.spaces.Box(-10.0, 10.0, shape=(4,), dtype=np.float32),
                "gripper_opening": gym.spaces.Box(0.0, OPEN_GAP, shape=(1,), dtype=np.float32),
                **self._tactile_spaces(),
            }
        )

    def object_height(self) -> float:
        """How far the object in play is above where it rested on the table (m)."""
        z = self.data.xpos[self._bodies[self.object]][2]
        return float(z - self._rest_z[self.object])

    def _observe(self) -> dict:
        d = self.data
        q = d.qpos[self._qpos]
        opening = np.clip(OPEN_GAP - q[2] - q[3], 0.0, OPEN_GAP)
        return {
            "joint_pos": np.clip(q, -0.2, 0.2).astype(np.float32),
            "joint_vel": np.clip(d.qvel[self._dof], -10.0, 10.0).astype(np.float32),
            "gripper_opening": np.array([opening], dtype=np.float32),
            **self._tactile_obs(),
        }

    def _info(self, obs: dict) -> dict:
        contacts = int((obs["tactile_depth"].reshape(2, -1).max(axis=1) > 0).sum())
        height = self.object_height()
        info = {
            "object": self.object,
            "object_height": height,
            "contacts": contacts,
            "is_success": bool(contacts == 2 and height >= self.lift_target),
        }
        if self.coupling:
            info["gel_force"] = np.array(
                [tacrom.outputs(self.model, self.data, s)["force"] for s in SENSORS]
            )
        return info

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        m, d, rng = self.model, self.data, self.np_random
        if self.coupling and m.opt.timestep > COUPLED_STEP_LIMIT * (1 + 1e-9):
            warnings.warn(
                f"tacrom/GripperLift-v1 with coupled gels at a physics step of "
                f"{m.opt.timestep * 1e3:g} ms: beyond {COUPLED_STEP_LIMIT * 1e3:g} ms the "
                "gels can bounce the held object between the fingers by millimetres (at "
                "13.3 ms in 2 of 15 measured grasps, at 20 ms in all; docs/rl.md, 'A long "
                "physics step: the fingers\' damping, taken after the solve'); use a timestep "
                "of at most "
                f"{COUPLED_STEP_LIMIT * 1e3:g} ms",
                RuntimeWarning,
                stacklevel=2,
            )
        mujoco.mj_resetData(m, d)
        if self.object_choice == "random":
            self.object = OBJECTS[int(rng.integers(len(OBJECTS)))]
        else:
            self.object = self.object_choice
        parked = iter(PARKING)
        for name in OBJECTS:
            adr = self._free[name]
            if name == self.object:
                x, y = 0.0, rng.uniform(-0.004, 0.004)
                yaw = rng.uniform(-0.15, 0.15)
            else:
                (x, y), yaw = next(parked), 0.0
            d.qpos[adr : adr + 3] = [x, y, self._rest_z[name]]
            d.qpos[adr + 3 : adr + 7] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        d.qpos[self._qpos] = [0.0, START_LIFT, 0.0, 0.0]
        d.ctrl[:] = [0.0, START_LIFT, 0.0, 0.0]
        # The filtered targets start where the servos hold the gripper.
        for i in range(m.nu):
            if m.actuator_actadr[i] >= 0:
                d.act[m.actuator_actadr[i]] = d.ctrl[i]
        mujoco.mj_forward(m, d)
        obs = self._observe()
        return obs, self._info(obs)

    def step(self, action) -> tuple[dict, float, bool, bool, dict[str, Any]]:
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        close = 0.5 * CLOSE_RANGE * (a[2] + 1.0)
        self.data.ctrl[:] = [CARRY_RANGE * a[0], 0.5 * LIFT_RANGE * (a[1] + 1.0), close, close]
        self._simulate()
        obs = self._observe()
        info = self._info(obs)
        reward = 0.25 * info["contacts"] + min(max(info["object_height"], 0.0) / self.lift_target, 1.0)
        return obs, float(reward), False, False, info
