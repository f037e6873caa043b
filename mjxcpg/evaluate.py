"""Evaluation of learned policies as in the paper's evaluation section, from a checkpoint.

Every learner's final policy (its mean a_max g(mu(x)), no exploration noise) walks from the
standing pose, all learners (and push directions, magnitudes) in one batch, in lockstep: one
pure step per robot, ``vmap`` over robots, ``lax.scan`` over control periods, a thin Python
loop over chunks that stops as soon as every robot has finished its protocol or fallen.
Finished and fallen robots are passed to the engine as inactive, so the C engines skip them.

What is measured (choices and reasons in ``docs/evaluation.md``):

* **velocity** (Fig 7): the mean forward speed over ``fixed_point_steps`` whole gait cycles
  (left touchdown to left touchdown) after ``settle_seconds``;
* **return map** (Fig 8): the step length at each left touchdown; its mean over the same
  unperturbed cycles is the fixed point; then ``perturbations`` times, at a random moment, the
  target of (q5 - q6) is offset until the next left touchdown (x_n, right after the
  perturbation), and the touchdown after it gives x_{n+1}; the least-squares slope of
  x_{n+1} on x_n is the return map's eigenvalue (paper: -0.0101);
* **slopes**: the contiguous range of floor inclinations around 0, in 1-degree steps, over
  which the policy walks ``slope_seconds`` without a fall (paper: +3 to -4 degrees);
* **pushes**: the largest impulse, forward, backward, to the left and to the right, applied
  to the pelvis for ``push_seconds`` from the first left touchdown after
  ``push_after_seconds``, that the gait survives for ``push_observe_seconds`` (bisection,
  every learner and direction in one batch per round).

Everything random (perturbation times and sizes) is drawn from ``EvalParams.seed`` and the
learner's index in its run, so an evaluation is deterministic and a learner's figures do not
depend on which other learners are evaluated with it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxcpg import cpg, ik, runs, xla
from mjxcpg.controller import control_step, joint_targets
from mjxcpg.learner import Task, policy_mean_feedback
from mjxcpg.robot import LEG_JOINTS, Layout, Observation, observe
from mjxcpg.sim import Simulation, make_simulation
from mjxcpg.walk import has_fallen


@dataclasses.dataclass(frozen=True)
class EvalParams:
    """Protocol constants of every evaluation (defaults: the paper's counts where it gives them)."""

    seed: int = 0
    settle_seconds: float = 4.0         # walking from standing settles within a few cycles
    # touchdown detection on the left sole's vertical force, in units of body weight m g
    touchdown_force: float = 0.25       # a touchdown is the force rising past this ...
    liftoff_force: float = 0.05         # ... after the sole was unloaded (below this) ...
    min_airborne_seconds: float = 0.08  # ... for at least this long (ignores contact chatter)
    # velocity and return map (Figs 7, 8)
    fixed_point_steps: int = 100        # unperturbed left touchdowns: velocity and fixed point
    perturbations: int = 50
    perturbation_amplitude: float = 0.5  # offset of the (q5 - q6) target, uniform in +/- this
    recovery_seconds: float = 2.0       # unperturbed walking between a perturbation's x_{n+1} and the next
    onset_jitter_seconds: float = 1.0   # + uniform in [0, this): a random phase of the gait cycle
    max_cycle_seconds: float = 2.0      # bounds the protocol's length for a robot that stops stepping
    # slopes
    slope_seconds: float = 20.0
    max_slope_deg: int = 15
    # pushes
    push_after_seconds: float = 4.0
    push_seconds: float = 0.08          # 10 control periods: short against a 0.9 s gait cycle
    push_observe_seconds: float = 4.0
    max_impulse: float = 4.0            # N s; bisection on [0, max_impulse]
    push_rounds: int = 7
    chunk_seconds: float = 10.0


PUSH_DIRECTIONS = {"forward": (1.0, 0.0, 0.0), "backward": (-1.0, 0.0, 0.0),
                   "left": (0.0, 1.0, 0.0), "right": (0.0, -1.0, 0.0)}

# Return-map protocol phases
BASELINE, WAITING, PERTURBING, AFTER, DONE = range(5)


@dataclasses.dataclass(frozen=True)
class Protocol:
    """What one evaluation walk does, in control periods (static: part of the compiled walk).

    ``mode`` is ``"steady"`` (walk ``max_steps``), ``"return_map"`` (baseline touchdowns, then
    perturbations, then done) or ``"push"`` (one push at a left touchdown, then observe).
    """

    mode: str
    max_steps: int
    settle_steps: int
    capacity: int                       # touchdowns logged per robot
    touchdown_force: float              # newtons
    liftoff_force: float
    min_airborne_steps: int
    fixed_point_steps: int = 0
    perturbations: int = 0
    amplitude: float = 0.0
    recovery_steps: int = 0
    jitter_steps: int = 1
    push_after_steps: int = 0
    push_steps: int = 0
    observe_steps: int = 0


def make_protocol(mode: str, params: EvalParams, layout: Layout, dt: float) -> Protocol:
    """The ``mode`` protocol of ``params`` for a robot of ``layout`` at control period ``dt``."""
    def steps(seconds: float) -> int:
        return max(1, round(seconds / dt))

    common = dict(settle_steps=steps(params.settle_seconds),
                  touchdown_force=params.touchdown_force * layout.weight,
                  liftoff_force=params.liftoff_force * layout.weight,
                  min_airborne_steps=steps(params.min_airborne_seconds))
    if mode == "steady":
        seconds = params.slope_seconds
        return Protocol(mode, steps(seconds), capacity=math.ceil(seconds / 0.2), **common)
    if mode == "return_map":
        cycles = params.fixed_point_steps + 1 + params.perturbations * 2
        seconds = (params.settle_seconds + cycles * params.max_cycle_seconds
                   + params.perturbations * (params.recovery_seconds + params.onset_jitter_seconds))
        return Protocol(mode, steps(seconds), capacity=math.ceil(seconds / 0.2),
                        fixed_point_steps=params.fixed_point_steps, perturbations=params.perturbations,
                        amplitude=params.perturbation_amplitude, recovery_steps=steps(params.recovery_seconds),
                        jitter_steps=steps(params.onset_jitter_seconds), **common)
    if mode == "push":
        seconds = (params.push_after_seconds + params.max_cycle_seconds + params.push_seconds
                   + params.push_observe_seconds)
        return Protocol(mode, steps(seconds), capacity=math.ceil(seconds / 0.2),
                        push_after_steps=steps(params.push_after_seconds), push_steps=steps(params.push_seconds),
                        observe_steps=steps(params.push_observe_seconds), **common)
    raise ValueError(f"unknown evaluation protocol {mode!r}")


class LegJoints(NamedTuple):
    """qpos addresses of (hip pitch, knee) of each leg: the joints of the sagittal leg FK."""

    left: tuple[int, int]
    right: tuple[int, int]

    @classmethod
    def of(cls, model: mujoco.MjModel) -> LegJoints:
        def address(side: str, joint: str) -> int:
            return int(model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{side}_{joint}")])
        pitch, knee = LEG_JOINTS.index("hip_pitch"), LEG_JOINTS.index("knee")
        return cls(*(tuple(address(side, LEG_JOINTS[k]) for k in (pitch, knee)) for side in ("l", "r")))


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


def perturbed_targets(task: Task, q: jax.Array, offset: jax.Array) -> jax.Array:
    """Servo targets with the target of (q5 - q6) offset by ``offset`` (eqs 6-7).

    p_x^l = X_0 - A_x (q5 - q6 + offset), p_x^r = X_0 + A_x (q5 - q6 + offset): the legs'
    fore-aft tip offset (right minus left) changes by 2 A_x offset, the CPG itself is untouched.
    """
    return joint_targets(task.controller, task.layout, q.at[4].add(offset))


class Probe(NamedTuple):
    """One robot's protocol state."""

    phase: jax.Array                # return map: BASELINE ... DONE
    baseline: jax.Array             # unperturbed touchdowns counted after settling
    perturbation: jax.Array         # index of the current (or next) perturbation
    next_onset: jax.Array           # control period at which it starts
    offsets: jax.Array              # (perturbations,) their (q5 - q6) target offsets
    onset_jitter: jax.Array         # (perturbations,) their random delays, control periods
    perturbed_touchdown: jax.Array  # (perturbations,) touchdown index of each x_n, -1 if none
    push: jax.Array                 # (3,) force during the push, newtons
    push_start: jax.Array           # control period of the push, -1 before it


class TouchdownLog(NamedTuple):
    """Left touchdowns of one robot: count, then per touchdown its control period, the step
    length and the pelvis' forward position."""

    count: jax.Array
    step: jax.Array
    length: jax.Array
    position: jax.Array


class EvalState(NamedTuple):
    """A batch of robots under one protocol; ``step`` is the shared control period."""

    physics: Any
    cpg: cpg.CPGState
    step: jax.Array
    fallen: jax.Array
    fall_step: jax.Array
    skipped: jax.Array              # robots excluded from the start (never stepped)
    unloaded_steps: jax.Array       # control periods the left sole has been unloaded
    probe: Probe
    log: TouchdownLog


def init_probe(protocol: Protocol, key: jax.Array, push: jax.Array) -> Probe:
    """One robot's protocol state: its perturbation offsets and timing drawn from ``key``."""
    n = max(protocol.perturbations, 1)
    offset_key, jitter_key = jax.random.split(key)
    return Probe(
        phase=jnp.int32(BASELINE), baseline=jnp.int32(0), perturbation=jnp.int32(0),
        next_onset=jnp.int32(0),
        offsets=protocol.amplitude * jax.random.uniform(offset_key, (n,), minval=-1.0, maxval=1.0),
        onset_jitter=jax.random.randint(jitter_key, (n,), 0, protocol.jitter_steps),
        perturbed_touchdown=jnp.full(n, -1, jnp.int32),
        push=jnp.asarray(push, jnp.float32), push_start=jnp.int32(-1))


def init_eval(sim: Simulation, protocol: Protocol, keys: jax.Array, pushes: jax.Array | None = None,
              skipped: jax.Array | None = None) -> EvalState:
    """A batch of ``len(keys)`` robots standing, with their protocol state."""
    batch = keys.shape[0]
    pushes = jnp.zeros((batch, 3), jnp.float32) if pushes is None else jnp.asarray(pushes, jnp.float32)
    c = protocol.capacity
    state = cpg.init_state()
    return EvalState(
        physics=sim.engine.init(sim.qpos0, batch),
        cpg=jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), state),
        step=jnp.int32(0), fallen=jnp.zeros(batch, bool), fall_step=jnp.full(batch, -1, jnp.int32),
        skipped=jnp.zeros(batch, bool) if skipped is None else jnp.asarray(skipped, bool),
        unloaded_steps=jnp.zeros(batch, jnp.int32),
        probe=jax.vmap(functools.partial(init_probe, protocol))(keys, pushes),
        log=TouchdownLog(count=jnp.zeros(batch, jnp.int32), step=jnp.full((batch, c), -1, jnp.int32),
                         length=jnp.full((batch, c), jnp.nan, jnp.float32),
                         position=jnp.full((batch, c), jnp.nan, jnp.float32)))


def advance_probe(protocol: Protocol, probe: Probe, t: jax.Array, touchdown: jax.Array,
                  touchdown_index: jax.Array) -> Probe:
    """The protocol's reaction to control period ``t`` and a left touchdown, if there is one."""
    if protocol.mode == "push":
        start = (probe.push_start < 0) & touchdown & (t >= protocol.push_after_steps)
        return probe._replace(push_start=jnp.where(start, t, probe.push_start))
    if protocol.mode != "return_map":
        return probe
    k = probe.perturbation
    settled = t >= protocol.settle_steps
    baseline = probe.baseline + (touchdown & settled & (probe.phase == BASELINE)).astype(jnp.int32)
    begin_waiting = (probe.phase == BASELINE) & (baseline >= protocol.fixed_point_steps + 1)
    onset = (probe.phase == WAITING) & (t >= probe.next_onset)
    landed = (probe.phase == PERTURBING) & touchdown
    next_one = (probe.phase == AFTER) & touchdown
    k_next = k + next_one.astype(jnp.int32)
    schedule = t + protocol.recovery_steps + probe.onset_jitter[jnp.minimum(k_next, probe.onset_jitter.shape[0] - 1)]
    phase = jnp.select(
        [begin_waiting, onset, landed, next_one & (k_next >= protocol.perturbations), next_one],
        [WAITING if protocol.perturbations else DONE, PERTURBING, AFTER, DONE, WAITING], probe.phase)
    next_onset = jnp.where(begin_waiting, t + probe.onset_jitter[0],
                           jnp.where(next_one, schedule, probe.next_onset))
    recorded = probe.perturbed_touchdown.at[k].set(
        jnp.where(landed, touchdown_index, probe.perturbed_touchdown[k]))
    return probe._replace(phase=phase.astype(jnp.int32), baseline=baseline, perturbation=k_next,
                          next_onset=next_onset, perturbed_touchdown=recorded)


def probe_drive(protocol: Protocol, probe: Probe, t: jax.Array) -> tuple[jax.Array, jax.Array]:
    """This period's (q5 - q6) target offset and pelvis force."""
    k = jnp.minimum(probe.perturbation, probe.offsets.shape[0] - 1)
    offset = jnp.where(probe.phase == PERTURBING, probe.offsets[k], 0.0)
    pushing = (probe.push_start >= 0) & (t < probe.push_start + protocol.push_steps)
    return offset, jnp.where(pushing, probe.push, 0.0)


def probe_finished(protocol: Protocol, probe: Probe, t: jax.Array) -> jax.Array:
    if protocol.mode == "return_map":
        return probe.phase == DONE
    if protocol.mode == "push":
        return (probe.push_start >= 0) & (t >= probe.push_start + protocol.push_steps + protocol.observe_steps)
    return jnp.bool_(False)


def is_done(protocol: Protocol, state: EvalState) -> jax.Array:
    """Per robot: fallen, skipped, out of time or through its protocol."""
    finished = jax.vmap(lambda p: probe_finished(protocol, p, state.step))(state.probe)
    return state.fallen | state.skipped | finished | (state.step >= protocol.max_steps)


def make_eval_chunk(sim: Simulation, task: Task, protocol: Protocol, steps: int) -> Callable:
    """A jitted ``chunk(state, weights) -> state`` advancing the batch by ``steps`` periods."""
    feedback = policy_mean_feedback(task)
    joints = LegJoints.of(sim.model)
    layout, engine = sim.layout, sim.engine
    pushing = protocol.mode == "push"

    def one_robot(t, cpg_state, sensors, weights, unloaded, log, probe, active):
        obs = observe(layout, sensors)
        fell = has_fallen(obs)
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
            position=log.position.at[slot].set(jnp.where(write, obs.forward_position, log.position[slot])))
        probe = advance_probe(protocol, probe, t, touchdown, index)
        offset, force = probe_drive(protocol, probe, t)
        a5 = feedback(obs, weights)
        cpg_state, _ = control_step(task.controller, layout, cpg_state, obs, a5)
        ctrl = perturbed_targets(task, cpg.output(cpg_state), offset)
        return cpg_state, ctrl, force, fell, unloaded, log, probe

    def body(state: EvalState, weights):
        active = ~is_done(protocol, state)
        cpg_state, ctrl, force, fell, unloaded, log, probe = jax.vmap(
            one_robot, in_axes=(None, 0, 0, 0, 0, 0, 0, 0))(
            state.step, state.cpg, engine.sensors(state.physics), weights, state.unloaded_steps,
            state.log, state.probe, active)
        fell = active & fell
        physics = engine.step(state.physics, ctrl, active & ~fell,
                              **({"pelvis_force": force} if pushing else {}))
        def keep(new, old):  # robots that are done keep their state
            return jax.tree.map(
                lambda n, o: jnp.where(active.reshape(active.shape + (1,) * (n.ndim - 1)), n, o), new, old)

        return EvalState(
            physics=physics, cpg=keep(cpg_state, state.cpg), step=state.step + 1,
            fallen=state.fallen | fell, fall_step=jnp.where(fell, state.step, state.fall_step),
            skipped=state.skipped, unloaded_steps=keep(unloaded, state.unloaded_steps),
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


# ---------------------------------------------------------------- analysis (host side)

def _cycles(log: TouchdownLog, k: int, first: int, cycles: int, dt: float) -> tuple[float, float, float]:
    """Over up to ``cycles`` gait cycles (left touchdown to left touchdown) from touchdown
    ``first``: the mean forward speed, the mean step length at their starting touchdowns and
    the mean cycle time (NaN when fewer than one cycle was logged)."""
    n = min(cycles + 1, int(log.count[k]) - first, log.step.shape[1] - first)
    if n < 2:
        return float("nan"), float("nan"), float("nan")
    steps = log.step[k, first:first + n]
    span = (steps[-1] - steps[0]) * dt
    return (float((log.position[k, first + n - 1] - log.position[k, first]) / span),
            float(np.mean(log.length[k, first:first + n - 1])), float(span / (n - 1)))


def least_squares_slope(x: np.ndarray, y: np.ndarray) -> dict:
    """Slope, intercept and the slope's standard error of the least-squares line y = a x + b."""
    if len(x) < 3 or np.ptp(x) == 0:
        return {"slope": None, "intercept": None, "slope_stderr": None}
    design = np.stack([x, np.ones_like(x)], axis=1)
    (a, b), residual, *_ = np.linalg.lstsq(design, y, rcond=None)
    dof = len(x) - 2
    sigma2 = float(residual[0]) / dof if len(residual) and dof > 0 else 0.0
    stderr = math.sqrt(sigma2 / np.sum((x - x.mean()) ** 2))
    return {"slope": float(a), "intercept": float(b), "slope_stderr": stderr}


def return_map_results(state: EvalState, protocol: Protocol, dt: float) -> list[dict]:
    """Per robot: velocity, fixed point, the (x_n, x_{n+1}) pairs and the eigenvalue."""
    out = []
    log, probe = state.log, state.probe
    for k in range(log.count.shape[0]):
        first = _first_settled(log, k, protocol)
        velocity, fixed_point, cycle = _cycles(log, k, first, protocol.fixed_point_steps, dt)
        pairs = [(float(log.length[k, i]), float(log.length[k, i + 1]), float(probe.offsets[k, j]))
                 for j, i in enumerate(probe.perturbed_touchdown[k])
                 if i >= 0 and i + 1 < min(int(log.count[k]), protocol.capacity)]
        x_n = np.array([p[0] for p in pairs])
        x_next = np.array([p[1] for p in pairs])
        fit = least_squares_slope(x_n, x_next)
        out.append({
            "fell": bool(state.fallen[k]),
            "fall_seconds": float(state.fall_step[k] * dt) if state.fallen[k] else None,
            "mean_vx": velocity, "gait_cycle_s": cycle,
            "fixed_point": fixed_point,
            "fixed_point_steps": int(np.clip(int(log.count[k]) - first - 1, 0, protocol.fixed_point_steps)),
            "perturbations": len(pairs), "x_n": x_n.tolist(), "x_next": x_next.tolist(),
            "offsets": [p[2] for p in pairs],
            "eigenvalue": fit["slope"], "eigenvalue_stderr": fit["slope_stderr"],
            "intercept": fit["intercept"],
            "stable": None if fit["slope"] is None else abs(fit["slope"]) < 1,
        })
    return out


# ---------------------------------------------------------------- the evaluations

def evaluate_return_map(sim: Simulation, task: Task, weights: Any, learners: Sequence[int],
                        params: EvalParams) -> list[dict]:
    """Fig 7's velocity and Fig 8's return map of every learner, one batch."""
    protocol = make_protocol("return_map", params, sim.layout, sim.control_dt)
    state = make_runner(sim, task, protocol, params)(weights, learner_keys(params.seed, learners, 8))
    return return_map_results(state, protocol, sim.control_dt)


def evaluate_slopes(run_sim: Simulation, task: Task, weights: Any, learners: Sequence[int],
                    params: EvalParams, engine: str | None = None, robot: str = "nominal") -> list[dict]:
    """Walk ``slope_seconds`` on floors tilted 0, +1, +2, ... and -1, -2, ... degrees.

    Each direction stops at the first inclination at which no learner is still walking every
    inclination from 0 to it; a learner that has fallen is skipped from then on.  Per learner:
    the largest uphill and downhill inclination of that contiguous range (None if it falls on
    the level floor) and, per inclination tried, whether it fell and its speed.
    """
    batch = len(learners)
    keys = learner_keys(params.seed, learners, 5)
    per_slope: dict[int, list[dict]] = {}
    limits = {+1: [None] * batch, -1: [None] * batch}
    walking_level = np.ones(batch, bool)
    for direction in (+1, -1):
        walking = walking_level.copy()
        start = 0 if direction > 0 else 1
        for degrees in range(start, params.max_slope_deg + 1):
            slope = direction * degrees
            if not walking.any():
                break
            sim = make_simulation(engine or run_sim.engine.name, float(slope), params=run_sim.params,
                                  physics_dt=run_sim.model.opt.timestep, robot=robot)
            protocol = make_protocol("steady", params, sim.layout, sim.control_dt)
            state = make_runner(sim, task, protocol, params)(weights, keys, skipped=jnp.asarray(~walking))
            rows = []
            for k in range(batch):
                velocity = _cycles(state.log, k, _first_settled(state.log, k, protocol),
                                   protocol.capacity, sim.control_dt)[0] if walking[k] else None
                velocity = None if velocity is None or math.isnan(velocity) else velocity
                rows.append({"tried": bool(walking[k]), "fell": bool(state.fallen[k]) if walking[k] else None,
                             "mean_vx": velocity})
            per_slope[slope] = rows
            survived = walking & ~np.asarray(state.fallen)
            for k in np.flatnonzero(survived):
                limits[direction][k] = slope
            if slope == 0:
                walking_level = survived
            walking = survived
    return [{"uphill_deg": limits[+1][k],
             "downhill_deg": limits[-1][k] if limits[-1][k] is not None else (0 if limits[+1][k] is not None else None),
             "per_slope": {str(s): per_slope[s][k] for s in sorted(per_slope)}}
            for k in range(batch)]


def _first_settled(log: TouchdownLog, k: int, protocol: Protocol) -> int:
    settled = np.flatnonzero(log.step[k] >= protocol.settle_steps)
    return int(settled[0]) if len(settled) else int(log.count[k])


def evaluate_pushes(sim: Simulation, task: Task, weights: Any, learners: Sequence[int],
                    params: EvalParams) -> list[dict]:
    """Largest survived impulse per learner and direction: bisection on [0, max_impulse].

    Each round walks every (learner, direction) pair at its current midpoint, all in one
    batch; surviving raises the lower end, falling lowers the upper end.  The figure is the
    largest impulse survived (0 if none was), ``capped`` when every tried impulse was survived.
    """
    protocol = make_protocol("push", params, sim.layout, sim.control_dt)
    names = list(PUSH_DIRECTIONS)
    directions = np.array([PUSH_DIRECTIONS[n] for n in names], np.float32)
    batch = len(learners) * len(names)
    robot_weights = jax.tree.map(lambda w: jnp.repeat(w, len(names), axis=0), weights)
    keys = jnp.repeat(learner_keys(params.seed, learners, 3), len(names), axis=0)
    low, high = np.zeros(batch), np.full(batch, params.max_impulse)
    survived_any = np.zeros(batch, bool)
    push_s = protocol.push_steps * sim.control_dt
    run = make_runner(sim, task, protocol, params)
    for _ in range(params.push_rounds):
        impulse = (low + high) / 2
        forces = np.tile(directions, (len(learners), 1)) * (impulse / push_s)[:, None]
        state = run(robot_weights, keys, pushes=jnp.asarray(forces))
        survived = ~np.asarray(state.fallen) & (np.asarray(state.probe.push_start) >= 0)
        low = np.where(survived, impulse, low)
        high = np.where(survived, high, impulse)
        survived_any |= survived
    out = []
    for k in range(len(learners)):
        rows = slice(k * len(names), (k + 1) * len(names))
        out.append({name: {"impulse": float(lo) if ok else 0.0, "capped": bool(hi == params.max_impulse)}
                    for name, lo, hi, ok in zip(names, low[rows], high[rows], survived_any[rows])})
    return out


def evaluate_run(spec, sim: Simulation, task: Task, state, learners: Sequence[int] | None = None,
                 params: EvalParams = EvalParams(), robot: str = "nominal",
                 parts: Sequence[str] = ("return_map", "slopes", "pushes"),
                 progress: Callable[[str], None] | None = None) -> dict:
    """All evaluations of the chosen learners of a loaded run (``runs.load_run``)."""
    chosen = runs.check_learners(spec, learners)
    rows = jnp.asarray(chosen)
    weights = jax.tree.map(lambda w: w[rows], state.learners.weights)
    book = jax.device_get(state.learners.book)
    result = {"engine": sim.engine.name, "robot": robot, "params": dataclasses.asdict(params),
              "learners": [{"learner": k, "k_s": spec.k_s[k], "seed": spec.seeds[k],
                            "succeeded": bool(book.trials_to_success[k] >= 0),
                            "trials": int(book.trial[k])} for k in chosen]}
    say = progress or (lambda _: None)
    if "return_map" in parts:
        say("velocity and return map")
        for row, r in zip(result["learners"], evaluate_return_map(sim, task, weights, chosen, params)):
            row["return_map"] = r
    if "slopes" in parts:
        say("slopes")
        for row, r in zip(result["learners"], evaluate_slopes(sim, task, weights, chosen, params, robot=robot)):
            row["slopes"] = r
    if "pushes" in parts:
        say("pushes")
        for row, r in zip(result["learners"], evaluate_pushes(sim, task, weights, chosen, params)):
            row["pushes"] = r
    return result
