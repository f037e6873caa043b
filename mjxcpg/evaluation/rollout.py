"""The batched evaluation walk: every robot's final policy, its touchdown log and its
protocol, one pure step per robot, ``vmap`` over robots, ``lax.scan`` over control periods,
and a Python loop over chunks until every robot is done."""

from __future__ import annotations

import functools
from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import mujoco

from mjxcpg.control import ik
from mjxcpg.control.controller import ControllerState, after_hand_start, control_step, init_state
from mjxcpg.control.sim import Simulation
from mjxcpg.control.walk import has_fallen
from mjxcpg.evaluation.protocol import EvalParams, Probe, Protocol, advance_probe, init_probe, probe_drive, probe_finished
from mjxcpg.jaxutil import xla
from mjxcpg.learning.learner import Task, actor_feedback
from mjxcpg.physics.model import Layout, Observation, observe
from mjxcpg.robots.description import LEG_JOINTS, RobotDescription
from mjxcpg.robots.qrio import QRIO


class LegJoints(NamedTuple):
    """qpos addresses of (hip pitch, knee) of each leg: the joints of the sagittal leg FK."""

    left: tuple[int, int]
    right: tuple[int, int]

    @classmethod
    def of(cls, model: mujoco.MjModel, robot: RobotDescription = QRIO) -> LegJoints:
        def address(joint: str) -> int:
            return int(model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)])
        pitch, knee = LEG_JOINTS.index("hip_pitch"), LEG_JOINTS.index("knee")
        return cls(*(tuple(address(leg.joints[k]) for k in (pitch, knee)) for leg in robot.legs))


def step_length(layout: Layout, joints: LegJoints, qpos: jax.Array, obs: Observation) -> jax.Array:
    """Fore-aft distance from the right ankle to the left one, along the world's horizontal.

    Measured as the robot could: sagittal forward kinematics of each leg's hip pitch and knee
    (``ik.ankle_position``, pelvis frame, z down), the difference rotated by the pelvis pitch.
    Positive when the left foot is ahead, as at a left touchdown while walking forward.
    """
    def ankle(address: tuple[int, int]) -> jax.Array:
        angles = jnp.zeros(6, qpos.dtype).at[2].set(qpos[address[0]]).at[3].set(qpos[address[1]])
        return ik.ankle_position(angles, layout.geometry)
    dx, dz_down = ankle(joints.left) - ankle(joints.right)
    return jnp.cos(obs.pitch) * dx - jnp.sin(obs.pitch) * dz_down


class TouchdownLog(NamedTuple):
    """Left touchdowns of one robot: count, then per touchdown its control period, the step
    length, the pelvis' forward position, its heading (yaw, rad) and the actuators' positive
    work since the walk began (J)."""

    count: jax.Array
    step: jax.Array
    length: jax.Array
    position: jax.Array
    heading: jax.Array
    work: jax.Array


class EvalState(NamedTuple):
    """A batch of robots under one protocol; ``step`` is the shared control period."""

    physics: Any
    controller: ControllerState
    step: jax.Array
    fallen: jax.Array
    fall_step: jax.Array
    skipped: jax.Array              # robots excluded from the start (never stepped)
    unloaded_steps: jax.Array       # control periods the left sole has been unloaded
    work: jax.Array                 # the actuators' positive work since the walk began (J)
    probe: Probe
    log: TouchdownLog


def init_eval(sim: Simulation, protocol: Protocol, keys: jax.Array, pushes: jax.Array | None = None,
              skipped: jax.Array | None = None) -> EvalState:
    """A batch of ``len(keys)`` robots standing, with their protocol state."""
    batch = keys.shape[0]
    pushes = jnp.zeros((batch, 3), jnp.float32) if pushes is None else jnp.asarray(pushes, jnp.float32)
    c = protocol.capacity
    return EvalState(
        physics=sim.engine.init(sim.qpos0, batch),
        controller=jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), init_state()),
        step=jnp.int32(0), fallen=jnp.zeros(batch, bool), fall_step=jnp.full(batch, -1, jnp.int32),
        skipped=jnp.zeros(batch, bool) if skipped is None else jnp.asarray(skipped, bool),
        unloaded_steps=jnp.zeros(batch, jnp.int32), work=jnp.zeros(batch, jnp.float32),
        probe=jax.vmap(functools.partial(init_probe, protocol))(keys, pushes),
        log=TouchdownLog(count=jnp.zeros(batch, jnp.int32), step=jnp.full((batch, c), -1, jnp.int32),
                         length=jnp.full((batch, c), jnp.nan, jnp.float32),
                         position=jnp.full((batch, c), jnp.nan, jnp.float32),
                         heading=jnp.full((batch, c), jnp.nan, jnp.float32),
                         work=jnp.full((batch, c), jnp.nan, jnp.float32)))


def is_done(protocol: Protocol, state: EvalState) -> jax.Array:
    """Per robot: fallen, skipped, out of time or through its protocol."""
    finished = jax.vmap(lambda p: probe_finished(protocol, p, state.step))(state.probe)
    return state.fallen | state.skipped | finished | (state.step >= protocol.max_steps)


def make_eval_chunk(sim: Simulation, task: Task, protocol: Protocol, steps: int) -> Callable:
    """A jitted ``chunk(state, weights) -> state`` advancing the batch by ``steps`` periods."""
    feedback = actor_feedback(task)
    joints = LegJoints.of(sim.model)
    layout, engine = sim.layout, sim.engine
    pushing = protocol.mode == "push"

    def one_robot(t, controller_state, sensors, weights, unloaded, work, log, probe, active):
        obs = observe(layout, sensors)
        work = work + obs.positive_work  # through the period before this one
        fell = has_fallen(layout, obs)
        # Left touchdown: the sole loaded again after a long enough unloaded spell.
        touchdown = active & ~fell & (obs.force_left >= protocol.touchdown_force) & (
            unloaded >= protocol.min_airborne_steps)
        unloaded = jnp.where(obs.force_left < protocol.liftoff_force, unloaded + 1,
                             jnp.where(obs.force_left >= protocol.touchdown_force, 0, unloaded))
        index = log.count
        slot = jnp.minimum(index, protocol.capacity - 1)
        write = touchdown & (index < protocol.capacity)
        log = TouchdownLog(
            count=log.count + touchdown.astype(jnp.int32),
            step=log.step.at[slot].set(jnp.where(write, t, log.step[slot])),
            length=log.length.at[slot].set(jnp.where(
                write, step_length(layout, joints, sensors.qpos, obs), log.length[slot])),
            position=log.position.at[slot].set(jnp.where(write, obs.forward_position, log.position[slot])),
            heading=log.heading.at[slot].set(jnp.where(write, obs.heading, log.heading[slot])),
            work=log.work.at[slot].set(jnp.where(write, work, log.work[slot])))
        probe = advance_probe(protocol, probe, t, touchdown, index)
        offset, force = probe_drive(protocol, probe, t)
        action = after_hand_start(task.controller, obs, feedback(obs, weights), t, protocol.hand_steps)
        controller_state, ctrl = control_step(task.controller, layout, controller_state, obs, action, offset)
        return controller_state, ctrl, force, fell, unloaded, work, log, probe

    def body(state: EvalState, weights):
        active = ~is_done(protocol, state)
        controller_state, ctrl, force, fell, unloaded, work, log, probe = jax.vmap(
            one_robot, in_axes=(None, 0, 0, 0, 0, 0, 0, 0, 0))(
            state.step, state.controller, engine.sensors(state.physics), weights, state.unloaded_steps,
            state.work, state.log, state.probe, active)
        fell = active & fell
        physics = engine.step(state.physics, ctrl, active & ~fell,
                              **({"pelvis_force": force} if pushing else {}))
        def keep(new, old):  # robots that are done keep their state
            return jax.tree.map(
                lambda n, o: jnp.where(active.reshape(active.shape + (1,) * (n.ndim - 1)), n, o), new, old)

        return EvalState(
            physics=physics, controller=keep(controller_state, state.controller), step=state.step + 1,
            fallen=state.fallen | fell, fall_step=jnp.where(fell, state.step, state.fall_step),
            skipped=state.skipped, unloaded_steps=keep(unloaded, state.unloaded_steps),
            work=keep(work, state.work),
            probe=keep(probe, state.probe), log=keep(log, state.log))

    @xla.jit
    def chunk(state: EvalState, weights) -> EvalState:
        state, _ = jax.lax.scan(lambda s, _: (body(s, weights), None), state, None, length=steps)
        return state

    return chunk


def make_runner(sim: Simulation, task: Task, protocol: Protocol, params: EvalParams) -> Callable:
    """``run(weights, keys, pushes=None, skipped=None) -> EvalState``: chunks until every robot
    is done, the final state on the host.  The chunk is compiled once per runner (and batch
    shape), so repeated rounds (push bisection) reuse it."""
    steps = max(1, min(round(params.chunk_seconds / sim.control_dt), protocol.max_steps))
    chunk = make_eval_chunk(sim, task, protocol, steps)
    done = jax.jit(functools.partial(is_done, protocol))

    def run(weights: Any, keys: jax.Array, pushes: jax.Array | None = None,
            skipped: jax.Array | None = None) -> EvalState:
        state = init_eval(sim, protocol, keys, pushes, skipped)
        while not bool(jnp.all(done(state))):
            state = jax.block_until_ready(chunk(state, weights))
        return jax.device_get(state)

    return run


def learner_keys(seed: int, learners: Sequence[int], salt: int) -> jax.Array:
    """One key per learner, from the evaluation seed, an evaluation's salt and the learner's index."""
    base = jax.random.fold_in(jax.random.PRNGKey(seed), salt)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.asarray(learners, jnp.int32))
