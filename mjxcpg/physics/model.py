"""A robot's compiled model: loading (with a floor slope), its layout, and what its sensors read."""

from __future__ import annotations

import dataclasses
import importlib.resources
import math
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.robots.description import LegGeometry, RobotDescription
from mjxcpg.robots.qrio import QRIO

MAX_SLOPE_DEG = 30.0


def load_model(slope_deg: float = 0.0, path: Path | str | None = None,
               timestep: float | None = None, robot: RobotDescription = QRIO) -> mujoco.MjModel:
    """Compile ``robot``'s MJCF (or the one at ``path``) and tilt the floor by ``slope_deg``
    (positive: uphill along +x)."""
    if not -MAX_SLOPE_DEG <= slope_deg <= MAX_SLOPE_DEG:
        raise ValueError(f"slope must be within +/-{MAX_SLOPE_DEG:g} degrees, got {slope_deg:g}")
    # Package data, so that an installed (non-editable) mjxcpg finds its robot too.
    with importlib.resources.as_file(robot.mjcf_resource()) as default_path:
        spec = mujoco.MjSpec.from_file(str(path or default_path))
    model = with_power_sensors(spec).compile()
    half = math.radians(-slope_deg) / 2  # rotating the plane about +y by -slope tilts it uphill
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, robot.floor)
    model.geom_quat[floor] = [math.cos(half), 0.0, math.sin(half), 0.0]
    if timestep is not None:
        model.opt.timestep = timestep
    if slope_deg != 0.0:
        # MuJoCo C computes the frames of the world body's (static) geoms with the model's
        # constants: without this the C engines would keep a level floor.
        mujoco.mj_setConst(model, mujoco.MjData(model))
    return model


POWER_SENSOR_PREFIX = "power_"


def with_power_sensors(spec: mujoco.MjSpec) -> mujoco.MjSpec:
    """``spec`` with an ``actuatorfrc`` and an ``actuatorvel`` sensor per actuator, after its own
    sensors (whose addresses stay as they were): the actuators' mechanical power, force times
    velocity as MuJoCo applied them, whatever the servo law, its limits or its latency.
    Sensors do not act on the dynamics."""
    names = [actuator.name for actuator in spec.actuators]
    for kind, sensor_type in (("force", mujoco.mjtSensor.mjSENS_ACTUATORFRC),
                              ("velocity", mujoco.mjtSensor.mjSENS_ACTUATORVEL)):
        for name in names:
            spec.add_sensor(name=f"{POWER_SENSOR_PREFIX}{kind}_{name}", type=sensor_type,
                            objtype=mujoco.mjtObj.mjOBJ_ACTUATOR, objname=name)
    return spec


def power_sensor_slices(model: mujoco.MjModel) -> tuple[slice, slice]:
    """Where in sensordata ``with_power_sensors`` put the actuators' forces and velocities
    (each kind one sensor per actuator, in the actuators' order, one after another)."""
    def first(kind: str) -> int:
        name = f"{POWER_SENSOR_PREFIX}{kind}_{model.actuator(0).name}"
        index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
        if index < 0:
            raise ValueError("the model has no actuator power sensors (models come from load_model)")
        return int(model.sensor_adr[index])
    force, velocity = first("force"), first("velocity")
    return slice(force, force + model.nu), slice(velocity, velocity + model.nu)


def positive_power(force, velocity):
    """The actuators' positive mechanical power, sum over actuators of max(0, force x velocity)
    (W; NumPy or JAX arrays, actuators on the last axis): the numerator of the cost of
    transport (Collins et al., Science 2005), counting no energy back from an actuator that
    does negative work."""
    return (force * velocity).clip(min=0).sum(axis=-1)


@dataclasses.dataclass(frozen=True)
class Layout:
    """Addresses into qpos, ctrl and sensordata, read once from a compiled model."""

    nq: int
    nv: int
    nu: int
    left_leg_ctrl: tuple[int, ...]
    right_leg_ctrl: tuple[int, ...]
    ctrl_home: tuple[float, ...]      # servo targets of the joints the CPG does not move
    gyro: int
    quat: int
    left_touch: int
    right_touch: int
    weight: float                     # m g, newtons
    slope_tan: float
    geometry: LegGeometry
    hip_to_sole: tuple[float, float]  # pelvis centre to hip, ankle to sole bottom (m)
    fall_height: float                # pelvis height (m) below which the robot has fallen

    @classmethod
    def of(cls, model: mujoco.MjModel, robot: RobotDescription = QRIO) -> "Layout":
        def actuator(name: str) -> int:
            return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)

        def sensor(name: str) -> int:
            index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
            if index < 0:
                raise ValueError(f"the model has no sensor {name!r} (models come from load_model)")
            return int(model.sensor_adr[index])

        def body_offset(name: str) -> float:
            return -float(model.body_pos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)][2])

        floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, robot.floor)
        w, _, y, _ = model.geom_quat[floor]
        left = robot.left
        sole = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, left.sole)
        ankle_to_sole = -float(model.geom_pos[sole][2]) + float(model.geom_size[sole][2])
        home = np.zeros(model.nu)
        for name, target in robot.home_pose:
            home[actuator(name)] = target
        return cls(
            nq=model.nq, nv=model.nv, nu=model.nu,
            left_leg_ctrl=tuple(actuator(j) for j in left.joints),
            right_leg_ctrl=tuple(actuator(j) for j in robot.right.joints),
            ctrl_home=tuple(home),
            gyro=sensor(robot.gyro), quat=sensor(robot.orientation),
            left_touch=sensor(left.force), right_touch=sensor(robot.right.force),
            weight=float(model.body_subtreemass[1] * -model.opt.gravity[2]),
            slope_tan=float(-2 * w * y / (w * w - y * y)) if w * w != y * y else 0.0,
            geometry=LegGeometry(thigh=body_offset(left.shin), shin=body_offset(left.ankle)),
            hip_to_sole=(body_offset(left.hip), ankle_to_sole),
            fall_height=robot.gait.fall_height,
        )

    def pelvis_height(self, leg_length: float) -> float:
        """Pelvis height above flat ground when both legs stand at ``leg_length``."""
        return self.hip_to_sole[0] + leg_length + self.hip_to_sole[1]


class Sensors(NamedTuple):
    """Raw engine output for one robot (or a batch): the ground truth and the sensors."""

    qpos: jax.Array
    qvel: jax.Array
    sensordata: jax.Array
    # The actuators' positive mechanical work over the last control period (J): the power of
    # every physics step (``positive_power``), not only the last's, times the step.
    positive_work: jax.Array


class Observation(NamedTuple):
    """What the controller and the learner use, for one robot."""

    gyro: jax.Array          # pelvis angular velocity in its own frame (roll, pitch, yaw rates)
    roll: jax.Array          # pelvis roll, right-handed about the forward axis (left side up > 0)
    pitch: jax.Array
    force_left: jax.Array    # vertical sole forces (N)
    force_right: jax.Array
    height: jax.Array        # ground truth: pelvis height above the floor under it (m)
    forward_velocity: jax.Array  # ground truth: pelvis velocity along +x (m/s)
    lateral_velocity: jax.Array  # ground truth: pelvis velocity along +y, to the left (m/s)
    forward_position: jax.Array
    uprightness: jax.Array   # ground truth: z component of the pelvis' up axis
    heading: jax.Array       # ground truth: pelvis yaw about the world's z (rad, to the left > 0)
    positive_work: jax.Array  # ground truth: the actuators' over the last control period (J, ``Sensors``)


def observe(layout: Layout, sensors: Sensors) -> Observation:
    """Read one robot's observation from engine output (pure JAX)."""
    sd, qpos, qvel = sensors.sensordata, sensors.qpos, sensors.qvel
    w, x, y, z = (sd[layout.quat + k] for k in range(4))
    roll = jnp.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = jnp.arcsin(jnp.clip(2 * (w * y - z * x), -1.0, 1.0))
    qw, qx, qy, qz = (qpos[3 + k] for k in range(4))
    return Observation(
        gyro=sd[layout.gyro:layout.gyro + 3],
        roll=roll,
        pitch=pitch,
        force_left=sd[layout.left_touch],
        force_right=sd[layout.right_touch],
        height=qpos[2] - qpos[0] * layout.slope_tan,
        forward_velocity=qvel[0],
        lateral_velocity=qvel[1],
        forward_position=qpos[0],
        uprightness=1 - 2 * (qx * qx + qy * qy),
        heading=jnp.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz)),
        positive_work=sensors.positive_work,
    )

