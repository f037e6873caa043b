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
learner's index in its run, so an evaluation is deterministic and a learner's draws do not
depend on which other learners are evaluated with it (its figures can, by rounding, through
the batch's size: docs/evaluation.md).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from mjxcpg.control import walk
from mjxcpg.control.sim import Simulation
from mjxcpg.evaluation.protocol import PUSH_DIRECTIONS, EvalParams, Protocol, make_protocol
from mjxcpg.evaluation.rollout import EvalState, TouchdownLog, learner_keys, make_runner
from mjxcpg.learning.learner import Task


# ---------------------------------------------------------------- analysis (host side)

class Cycles(NamedTuple):
    """Means over whole gait cycles (left touchdown to left touchdown); NaN when fewer than
    one cycle was logged, ``cost_of_transport`` None unless the robot went forward."""

    mean_vx: float
    step_length: float
    cycle_s: float
    cost_of_transport: float | None


def _cycles(log: TouchdownLog, k: int, first: int, cycles: int, dt: float, weight: float) -> Cycles:
    """Over up to ``cycles`` gait cycles from touchdown ``first``: the mean forward speed, the
    mean step length at their starting touchdowns, the mean cycle time and the cost of
    transport along +x (``weight``: m g, newtons)."""
    n = min(cycles + 1, int(log.count[k]) - first, log.step.shape[1] - first)
    if n < 2:
        return Cycles(float("nan"), float("nan"), float("nan"), None)
    steps = log.step[k, first:first + n]
    span = (steps[-1] - steps[0]) * dt
    distance = float(log.position[k, first + n - 1] - log.position[k, first])
    work = float(log.work[k, first + n - 1]) - float(log.work[k, first])
    return Cycles(distance / span, float(np.mean(log.length[k, first:first + n - 1])), float(span / (n - 1)),
                  walk.cost_of_transport(work, weight, distance))


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


def _heading_drift(log: TouchdownLog, k: int, first: int, cycles: int) -> tuple[float | None, float | None]:
    """Over the touchdowns of ``cycles`` gait cycles from touchdown ``first``: the heading's
    change from the first to the last, and its largest departure from the first (degrees)."""
    n = min(cycles + 1, int(log.count[k]) - first, log.heading.shape[1] - first)
    if n < 2:
        return None, None
    heading = np.degrees(np.unwrap(np.asarray(log.heading[k, first:first + n], np.float64)))
    heading -= heading[0]
    return float(heading[-1]), float(heading[np.argmax(np.abs(heading))])


def return_map_results(state: EvalState, protocol: Protocol, dt: float, weight: float) -> list[dict]:
    """Per robot: velocity, fixed point, the (x_n, x_{n+1}) pairs and the eigenvalue; and how
    the unperturbed walk lasts: whether it fell before its last unperturbed cycle, its speed
    over the first and over the second half of those cycles, and its heading's drift."""
    out = []
    log, probe = state.log, state.probe
    for k in range(log.count.shape[0]):
        first = _first_settled(log, k, protocol)
        velocity, fixed_point, cycle, cost = _cycles(log, k, first, protocol.fixed_point_steps, dt, weight)
        half = protocol.fixed_point_steps // 2
        first_half_vx = _cycles(log, k, first, half, dt, weight).mean_vx
        last = first + protocol.fixed_point_steps  # the touchdown that ends the unperturbed cycles
        all_logged = min(int(log.count[k]), log.step.shape[1]) > last
        last_half_vx = _cycles(log, k, first + half, protocol.fixed_point_steps - half, dt, weight).mean_vx \
            if all_logged else float("nan")
        drift, largest = _heading_drift(log, k, first, protocol.fixed_point_steps)
        unperturbed_done = all_logged and (not state.fallen[k] or state.fall_step[k] > log.step[k, last])
        pairs = [(float(log.length[k, i]), float(log.length[k, i + 1]), float(probe.offsets[k, j]))
                 for j, i in enumerate(probe.perturbed_touchdown[k])
                 if i >= 0 and i + 1 < min(int(log.count[k]), protocol.capacity)]
        x_n = np.array([p[0] for p in pairs])
        x_next = np.array([p[1] for p in pairs])
        fit = least_squares_slope(x_n, x_next)
        out.append({
            "fell": bool(state.fallen[k]),
            "fall_seconds": float(state.fall_step[k] * dt) if state.fallen[k] else None,
            "mean_vx": velocity, "gait_cycle_s": cycle, "cost_of_transport": cost,
            "walked_unperturbed_cycles": bool(unperturbed_done),
            "mean_vx_first_half": first_half_vx, "mean_vx_last_half": last_half_vx,
            "heading_drift_deg": drift, "heading_largest_deg": largest,
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
    return return_map_results(state, protocol, sim.control_dt, sim.layout.weight)


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
            sim = run_sim.rebuild(engine=engine or run_sim.engine.name, slope_deg=float(slope), robot=robot)
            protocol = make_protocol("steady", params, sim.layout, sim.control_dt)
            state = make_runner(sim, task, protocol, params)(weights, keys, skipped=jnp.asarray(~walking))
            rows = []
            for k in range(batch):
                velocity = _cycles(state.log, k, _first_settled(state.log, k, protocol),
                                   protocol.capacity, sim.control_dt, sim.layout.weight).mean_vx if walking[k] else None
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
