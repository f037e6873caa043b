"""The reward's inputs measured as on the paper's hardware: no ground truth.

The paper's online learning on QRIO (its last section): "walking velocity was calculated by
the relative velocity of the stance leg with respect to the pelvis and the body height was
measured by the joint angles of the stance leg and the absolute body inclination derived from
integration of gyration sensor. We introduced digital filters to cut off the measurement
noise." Here, per control period and for one robot (pure JAX, ``vmap`` it):

1. **Inclination**: pelvis roll and pitch integrated from the gyro through the Euler-angle
   kinematics (ZYX convention, yaw ignored), with a leak toward level (time constant
   ``tilt_leak_s``): a first-order high-pass that keeps a gyro bias b from drifting the
   estimate (it settles at about b * tilt_leak_s instead of growing as b * t).
2. **Stance leg**: the one whose sole force sensor reads more, with a hysteresis of
   ``stance_margin_n`` so that sensor noise in double support does not toggle it.
3. **Forward kinematics** of both legs from their joint angles (the nominal link lengths)
   give the sole's centre, bottom face, relative to the pelvis; rotated by the estimated
   inclination into a level frame aligned with the pelvis' heading.
4. **Height** = the stance sole's depth below the pelvis in that frame (the sole is flat on
   the floor), low-passed with ``height_filter_s``.
5. **Velocity** = minus the rate of change of the stance sole's forward position relative to
   the pelvis (the stance sole does not move, so the pelvis moves the other way), by a
   backward difference over one period; the learner's velocity filter
   (``TrialParams.velocity_filter_s``) is the digital low-pass that follows.
6. **Fall**: the IMU's tilt past 60 degrees, the estimated height below the fall height, or a
   non-finite reading.

The estimate is close to the truth on a nominal walk: tests/test_hardware.py states the
tolerances.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.control.walk import FALL_UPRIGHTNESS
from mjxcpg.physics.model import Observation, Sensors
from mjxcpg.robots.description import LegNames, RobotDescription
from mjxcpg.robots.qrio import QRIO


@dataclasses.dataclass(frozen=True)
class LegChain:
    """One leg's nominal kinematics, pelvis to sole, read from the model.

    ``body_pos[k]``, ``body_quat[k]``: the k-th body's frame in its parent's; joint k turns
    about ``axes[k]`` at that frame's origin; ``sole`` is the centre of the sole's bottom face
    in the last body's frame; ``qpos`` the joints' addresses.
    """

    body_pos: tuple[tuple[float, float, float], ...]
    body_quat: tuple[tuple[float, float, float, float], ...]
    axes: tuple[tuple[float, float, float], ...]
    sole: tuple[float, float, float]
    qpos: tuple[int, ...]

    @classmethod
    def of(cls, model: mujoco.MjModel, leg: LegNames) -> "LegChain":
        joints = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in leg.joints]
        bodies = [int(model.jnt_bodyid[j]) for j in joints]
        for j in joints:
            if np.any(model.jnt_pos[j] != 0):
                raise ValueError(f"joint {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)} "
                                 "is not at its body's origin")
        sole = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, leg.sole)
        if model.geom_bodyid[sole] != bodies[-1] or np.any(model.geom_quat[sole] != [1, 0, 0, 0]):
            raise ValueError(f"{leg.sole} must be an unrotated box on the last leg body")
        bottom = model.geom_pos[sole] - [0.0, 0.0, model.geom_size[sole][2]]
        return cls(
            body_pos=tuple(tuple(map(float, model.body_pos[b])) for b in bodies),
            body_quat=tuple(tuple(map(float, model.body_quat[b])) for b in bodies),
            axes=tuple(tuple(map(float, model.jnt_axis[j])) for j in joints),
            sole=tuple(map(float, bottom)),
            qpos=tuple(int(model.jnt_qposadr[j]) for j in joints),
        )


@dataclasses.dataclass(frozen=True)
class EstimatorParams:
    """Static constants of the estimator (leg kinematics, sensor addresses, filters)."""

    left: LegChain
    right: LegChain
    gyro: int                      # sensordata address of the pelvis gyro
    left_force: int                # sensordata addresses of the sole force sensors
    right_force: int
    fall_height: float             # pelvis height (m) below which the robot has fallen
    tilt_leak_s: float = 1.0       # leak of the integrated gyro toward level (s)
    height_filter_s: float = 0.05  # low-pass of the stance-leg height (s)
    stance_margin_n: float = 5.0   # the other sole must read this much more to become the stance

    @classmethod
    def of(cls, model: mujoco.MjModel, robot: RobotDescription = QRIO, **filters: float) -> "EstimatorParams":
        def sensor(name: str) -> int:
            return int(model.sensor_adr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)])

        return cls(left=LegChain.of(model, robot.left), right=LegChain.of(model, robot.right),
                   gyro=sensor(robot.gyro), left_force=sensor(robot.left.force),
                   right_force=sensor(robot.right.force), fall_height=robot.gait.fall_height, **filters)


class EstimatorState(NamedTuple):
    tilt: jax.Array           # (2,) estimated pelvis roll and pitch (rad)
    soles: jax.Array          # (2, 3) left and right sole relative to the pelvis, level frame, last period
    height: jax.Array         # low-passed stance-leg height (m)
    stance_right: jax.Array   # the right leg is the stance leg
    has_previous: jax.Array   # soles holds last period's positions


class Estimate(NamedTuple):
    """What the reward and the fall test read on hardware."""

    height: jax.Array
    forward_velocity: jax.Array   # unfiltered; the learner low-passes it
    fallen: jax.Array
    tilt: jax.Array               # (2,) estimated roll, pitch
    stance_right: jax.Array


def init_state(params: EstimatorParams, standing_height: float) -> EstimatorState:
    """At rest, level, at ``standing_height``."""
    return EstimatorState(tilt=jnp.zeros(2, jnp.float32), soles=jnp.zeros((2, 3), jnp.float32),
                          height=jnp.float32(standing_height), stance_right=jnp.bool_(False),
                          has_previous=jnp.bool_(False))


def _axis_rotation(axis: jax.Array, angle: jax.Array) -> jax.Array:
    """Rodrigues' formula: the rotation by ``angle`` about the unit ``axis``."""
    k = jnp.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return jnp.eye(3) + jnp.sin(angle) * k + (1 - jnp.cos(angle)) * (k @ k)


def _quat_rotation(quat: tuple[float, float, float, float]) -> np.ndarray:
    out = np.empty(9)
    mujoco.mju_quat2Mat(out, np.asarray(quat, np.float64))
    return out.reshape(3, 3)


def sole_in_pelvis(chain: LegChain, qpos: jax.Array) -> jax.Array:
    """Forward kinematics: the sole's bottom centre in the pelvis frame, from the joint angles."""
    rotation, position = jnp.eye(3), jnp.zeros(3)
    for k, angle in enumerate(qpos[jnp.array(chain.qpos)]):
        position = position + rotation @ jnp.asarray(chain.body_pos[k])
        rotation = rotation @ jnp.asarray(_quat_rotation(chain.body_quat[k]), jnp.float32)
        rotation = rotation @ _axis_rotation(jnp.asarray(chain.axes[k]), angle)
    return position + rotation @ jnp.asarray(chain.sole)


def level_rotation(tilt: jax.Array) -> jax.Array:
    """Pelvis frame to the level frame of its heading: R_y(pitch) R_x(roll) (ZYX Euler, no yaw)."""
    roll, pitch = tilt[0], tilt[1]
    cr, sr, cp, sp = jnp.cos(roll), jnp.sin(roll), jnp.cos(pitch), jnp.sin(pitch)
    rx = jnp.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = jnp.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return ry @ rx


def integrate_tilt(params: EstimatorParams, tilt: jax.Array, gyro: jax.Array, dt: float) -> jax.Array:
    """One period of leaky gyro integration through the ZYX Euler-angle rates:
    d roll/dt = w_x + (w_y sin roll + w_z cos roll) tan pitch, d pitch/dt = w_y cos roll - w_z sin roll."""
    roll, pitch = tilt[0], tilt[1]
    rates = jnp.stack([
        gyro[0] + (gyro[1] * jnp.sin(roll) + gyro[2] * jnp.cos(roll)) * jnp.tan(pitch),
        gyro[1] * jnp.cos(roll) - gyro[2] * jnp.sin(roll),
    ])
    return tilt + dt * (rates - tilt / params.tilt_leak_s)


def estimate(params: EstimatorParams, state: EstimatorState, sensors: Sensors, obs: Observation,
             dt: float) -> tuple[EstimatorState, Estimate]:
    """One control period for one robot: reads joint angles, gyro and sole forces from
    ``sensors`` and the IMU tilt from ``obs`` (roll and pitch of the orientation sensor);
    never the simulator's pelvis position or velocity."""
    sd = sensors.sensordata
    gyro = jnp.nan_to_num(sd[params.gyro:params.gyro + 3])
    tilt = integrate_tilt(params, state.tilt, gyro, dt)
    rotation = level_rotation(tilt)
    soles = jnp.stack([rotation @ sole_in_pelvis(params.left, sensors.qpos),
                       rotation @ sole_in_pelvis(params.right, sensors.qpos)])
    difference = sd[params.right_force] - sd[params.left_force]
    stance_right = jnp.where(state.stance_right, difference > -params.stance_margin_n,
                             difference > params.stance_margin_n)
    stance = jnp.where(stance_right, soles[1], soles[0])
    previous = jnp.where(stance_right, state.soles[1], state.soles[0])
    forward_velocity = jnp.where(state.has_previous, -(stance[0] - previous[0]) / dt, 0.0)
    height = state.height + (dt / params.height_filter_s) * (-stance[2] - state.height)
    upright = jnp.cos(obs.roll) * jnp.cos(obs.pitch)
    finite = jnp.isfinite(height) & jnp.isfinite(forward_velocity) & jnp.isfinite(upright)
    fallen = ~finite | (height < params.fall_height) | (upright < FALL_UPRIGHTNESS)
    new_state = EstimatorState(tilt=tilt, soles=soles, height=height, stance_right=stance_right,
                               has_previous=jnp.bool_(True))
    return new_state, Estimate(height=height, forward_velocity=forward_velocity, fallen=fallen,
                               tilt=tilt, stance_right=stance_right)
