"""The evaluation protocols: their constants (``EvalParams``), what one walk does
(``Protocol``) and each robot's protocol state (``Probe``) with its pure per-period update."""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mjxcpg.physics.model import Layout


@dataclasses.dataclass(frozen=True)
class EvalParams:
    """Protocol constants of every evaluation (defaults: the paper's counts where it gives them)."""

    seed: int = 0
    settle_seconds: float = 4.0         # walking from standing settles within a few cycles
    hand_seconds: float = 0.0           # the hand-designed feedback first, as at a learning trial's start
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
    hand_steps: int = 0                 # periods of hand-designed feedback before the policy acts
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

    # Velocity, fixed point and pushes are measured after the settling time: the policy must
    # be acting by then.
    if params.hand_seconds < 0 or 0 < min(params.settle_seconds, params.push_after_seconds) <= params.hand_seconds:
        raise ValueError(f"hand_seconds must be in [0, {min(params.settle_seconds, params.push_after_seconds):g}) s, "
                         f"the settling time; got {params.hand_seconds:g}")

    common = dict(settle_steps=steps(params.settle_seconds),
                  touchdown_force=params.touchdown_force * layout.weight,
                  liftoff_force=params.liftoff_force * layout.weight,
                  min_airborne_steps=steps(params.min_airborne_seconds),
                  hand_steps=round(params.hand_seconds / dt))
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
