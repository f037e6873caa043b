"""The "hardware" robot: the nominal model with the mismatch a physical robot brings.

The mismatch (``HardwareMismatch``, values and reasons in ``docs/hardware.md``) has two parts:

* model changes applied once at load time (``perturbed_model``): every body's mass and
  rotational inertia scaled by a fixed factor drawn per body within +/-10% from a fixed seed,
  another sole-floor friction, softer servos (lower position gain, more joint damping and
  reflected rotor inertia);
* signal-path changes applied by an engine wrapper (``HardwareEngine``): servo targets reach
  the servos ``latency_periods`` control periods after they were computed, and the gyro and
  the sole force sensors read with noise (a per-robot gyro bias plus white noise).

The controller keeps the nominal model's ``Layout`` (the designer's belief: nominal weight in
the extensor response, nominal leg geometry in the inverse kinematics): only the simulated
physics and the sensor readings change, so the controller and the learner never know which
robot they drive.  Everything here is deterministic: the model perturbation is a function of
``model_seed``, the sensor noise of ``noise_seed`` and the robot's index in the batch.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg.physics.engines import Engine
from mjxcpg.physics.model import Sensors
from mjxcpg.robots.description import RobotDescription
from mjxcpg.robots.qrio import QRIO


@dataclasses.dataclass(frozen=True)
class HardwareMismatch:
    """What differs between the simulated QRIO-class robot and the "hardware" one.

    Chosen before any learned policy was tried on it; see ``docs/hardware.md``.
    """

    model_seed: int = 2005              # seed of the per-body mass and inertia factors
    mass_spread: float = 0.10           # body mass factor uniform in [1 - spread, 1 + spread]
    inertia_spread: float = 0.10        # body inertia factor, drawn independently of the mass's
    sole_friction: float = 0.7          # sliding friction of soles and floor (nominal 1.0)
    servo_kp_scale: float = 0.8         # position gain kp 150 -> 120 N m/rad
    joint_damping_add: float = 0.5      # N m s/rad added to every hinge (nominal 1.0)
    armature_scale: float = 2.0         # reflected rotor inertia 0.01 -> 0.02 kg m^2
    latency_periods: int = 2            # control periods between a target's computation and its use
    noise_seed: int = 0                 # seed of the sensor noise streams
    gyro_noise_std: float = 0.05        # rad/s, white, per axis and control period
    gyro_bias_std: float = 0.01         # rad/s, constant per robot and axis
    force_noise_std: float = 1.5        # N, white, per sole and control period
    contact_timeconst_scale: float = 1.0  # sole-floor contact time constant x this: a softer floor above 1


HARDWARE = HardwareMismatch()
# A harsher robot on a softer floor, every value beyond ``HARDWARE``'s (``docs/hardware.md``).
HARSH = HardwareMismatch(mass_spread=0.15, inertia_spread=0.15, sole_friction=0.5, servo_kp_scale=0.6,
                         joint_damping_add=1.0, armature_scale=3.0, latency_periods=4, gyro_noise_std=0.1,
                         gyro_bias_std=0.02, force_noise_std=3.0, contact_timeconst_scale=2.0)
# ``HARSH`` with the two mismatches pushed one step further again, as far beyond ``HARSH`` as it
# is beyond ``HARDWARE``: actuation latency and floor compliance (``docs/hardware.md``).
HARSHER = dataclasses.replace(HARSH, latency_periods=6, contact_timeconst_scale=3.0)
MISMATCHES = {"hardware": HARDWARE, "harsh": HARSH, "harsher": HARSHER}  # the robots that stand in for a physical one


def body_factors(model: mujoco.MjModel, mismatch: HardwareMismatch) -> tuple[np.ndarray, np.ndarray]:
    """The fixed (mass, inertia) scale factors of every body; 1 for the world body."""
    rng = np.random.default_rng(mismatch.model_seed)
    mass = 1 + rng.uniform(-mismatch.mass_spread, mismatch.mass_spread, model.nbody)
    inertia = 1 + rng.uniform(-mismatch.inertia_spread, mismatch.inertia_spread, model.nbody)
    mass[0] = inertia[0] = 1.0
    return mass, inertia


def perturbed_model(model: mujoco.MjModel, mismatch: HardwareMismatch = HARDWARE) -> mujoco.MjModel:
    """A copy of ``model`` with the hardware's mass, inertia, friction and servo mismatch.

    Friction of a contact is the larger of its two geoms', so every geom that collides (the
    floor and the soles' contact points) gets ``sole_friction``; a contact's time constant
    mixes its two geoms', so all of theirs are scaled.  Derived constants (subtree masses, the joint-space inertia at qpos0)
    are recomputed with ``mj_setConst``.
    """
    hw = copy.deepcopy(model)
    mass, inertia = body_factors(model, mismatch)
    hw.body_mass[:] = model.body_mass * mass
    hw.body_inertia[:] = model.body_inertia * inertia[:, None]
    colliding = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    hw.geom_friction[colliding, 0] = mismatch.sole_friction
    if mismatch.contact_timeconst_scale != 1.0:
        hw.geom_solref[colliding, 0] = model.geom_solref[colliding, 0] * mismatch.contact_timeconst_scale
    hw.actuator_gainprm[:, 0] = model.actuator_gainprm[:, 0] * mismatch.servo_kp_scale
    hw.actuator_biasprm[:, 1] = model.actuator_biasprm[:, 1] * mismatch.servo_kp_scale
    hinge_dofs = model.jnt_dofadr[model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE]
    hw.dof_damping[hinge_dofs] = model.dof_damping[hinge_dofs] + mismatch.joint_damping_add
    hw.dof_armature[hinge_dofs] = model.dof_armature[hinge_dofs] * mismatch.armature_scale
    mujoco.mj_setConst(hw, mujoco.MjData(hw))
    return hw


class HardwareState(NamedTuple):
    """The wrapped engine's state plus what the signal path between controller and robot holds."""

    inner: Any             # the wrapped engine's batched state
    queue: jax.Array       # (batch, latency_periods, nu): targets computed but not yet applied
    key: jax.Array         # (batch, 2) uint32: each robot's sensor-noise stream, one draw a period
    gyro_bias: jax.Array   # (batch, 3) rad/s


def _sensor_slice(model: mujoco.MjModel, name: str) -> tuple[int, int]:
    sensor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
    return int(model.sensor_adr[sensor]), int(model.sensor_dim[sensor])


class HardwareEngine(Engine):
    """Any engine with actuation latency and noisy gyro and sole force readings.

    Same interface as the engine it wraps, whose name it keeps.  ``step`` applies the targets
    computed ``latency_periods`` calls earlier (the standing pose's targets at first) and
    forwards any further keyword (e.g. an external force) to the wrapped engine.
    ``sensors`` adds the noise of the current period, drawn from the robot's key; ``step``
    advances the key, ``reset`` keeps it (noise does not replay from trial to trial).
    """

    def __init__(self, inner: Engine, mismatch: HardwareMismatch = HARDWARE, robot: RobotDescription = QRIO):
        super().__init__(inner.model, inner.substeps, robot.pelvis)
        self.inner = inner
        self.name = inner.name
        self.mismatch = mismatch
        self.robot = robot
        self._gyro = _sensor_slice(inner.model, robot.gyro)
        self._forces = tuple(_sensor_slice(inner.model, leg.force)[0] for leg in robot.legs)
        self._ctrl_qposadr = inner.model.jnt_qposadr[inner.model.actuator_trnid[:, 0]]

    def with_noise_seed(self, noise_seed: int) -> HardwareEngine:
        """This robot, its sensor noise drawn from ``noise_seed`` instead."""
        return HardwareEngine(self.inner, dataclasses.replace(self.mismatch, noise_seed=noise_seed), self.robot)

    def init(self, qpos: np.ndarray, batch: int) -> HardwareState:
        m = self.mismatch
        held = jnp.asarray(np.asarray(qpos)[self._ctrl_qposadr], jnp.float32)
        keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.PRNGKey(m.noise_seed), i))(jnp.arange(batch))
        bias_keys = jax.vmap(lambda k: jax.random.fold_in(k, 0x0b1a5))(keys)
        return HardwareState(
            inner=self.inner.init(qpos, batch),
            queue=jnp.broadcast_to(held, (batch, m.latency_periods, held.shape[0])),
            key=keys,
            gyro_bias=m.gyro_bias_std * jax.vmap(lambda k: jax.random.normal(k, (3,)))(bias_keys),
        )

    def step(self, state: HardwareState, ctrl: jax.Array, active: jax.Array | None = None,
             **kwargs) -> HardwareState:
        ctrl = ctrl.astype(state.queue.dtype)
        if self.mismatch.latency_periods == 0:
            applied, queue = ctrl, state.queue
        else:
            applied = state.queue[:, 0]
            queue = jnp.concatenate([state.queue[:, 1:], ctrl[:, None]], axis=1)
        if active is not None:
            queue = jnp.where(active[:, None, None], queue, state.queue)
        inner = self.inner.step(state.inner, applied, active, **kwargs)
        key = jax.vmap(lambda k: jax.random.split(k)[0])(state.key)
        return HardwareState(inner=inner, queue=queue, key=key, gyro_bias=state.gyro_bias)

    def sensors(self, state: HardwareState) -> Sensors:
        truth = self.inner.sensors(state.inner)
        return truth._replace(sensordata=jax.vmap(self._noisy)(truth.sensordata, state.key, state.gyro_bias))

    def _noisy(self, sensordata: jax.Array, key: jax.Array, gyro_bias: jax.Array) -> jax.Array:
        """One robot's readings: gyro + bias + white noise, sole forces + white noise (>= 0)."""
        m = self.mismatch
        gyro_key, force_key = jax.random.split(key)
        start, dim = self._gyro
        gyro = sensordata[start:start + dim] + gyro_bias + m.gyro_noise_std * jax.random.normal(gyro_key, (dim,))
        forces = jnp.array(self._forces)
        force = jnp.maximum(sensordata[forces] + m.force_noise_std * jax.random.normal(force_key, (2,)), 0.0)
        return sensordata.at[start:start + dim].set(gyro).at[forces].set(force)

    def reset(self, state: HardwareState, initial: HardwareState, mask: jax.Array) -> HardwareState:
        """Robots where ``mask`` holds stand again with a fresh queue; their noise stream goes on."""
        reset = super().reset(state, initial, mask)
        return reset._replace(key=state.key, gyro_bias=state.gyro_bias)

