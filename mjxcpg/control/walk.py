"""Walking without learning: run a controller on an engine and measure the gait."""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import chex
import jax
import jax.numpy as jnp
import numpy as np

from mjxcpg.control.controller import ControllerParams, ControllerState, after_hand_start, control_step, init_state, split_feedback
from mjxcpg.jaxutil import xla
from mjxcpg.physics.engines import Engine
from mjxcpg.physics.model import Layout, Observation, observe

FeedbackFn = Callable[[Observation, jax.Array], jax.Array]  # (obs, params) -> a5, or (a5, stepping)
FALL_UPRIGHTNESS = 0.5    # cos of 60 degrees of pelvis tilt


def has_fallen(layout: Layout, obs: Observation) -> jax.Array:
    """A fall is the body on the ground: pelvis below the robot's fall height
    (``Layout.fall_height``) or tilted, or the physics diverged."""
    finite = jnp.isfinite(obs.height) & jnp.isfinite(obs.uprightness) & jnp.all(jnp.isfinite(obs.gyro))
    return ~finite | (obs.height < layout.fall_height) | (obs.uprightness < FALL_UPRIGHTNESS)


class Trace(NamedTuple):
    """Per control step, per robot."""

    height: jax.Array
    forward_position: jax.Array
    force_left: jax.Array
    force_right: jax.Array
    roll: jax.Array
    a5: jax.Array
    fallen: jax.Array
    positive_work: jax.Array    # J, the actuators' over the period before (``Sensors``)
    qpos: jax.Array | None = None   # the full configuration, only from make_walk(record_qpos=True)
    cpg_z: jax.Array | None = None  # the CPG's membrane states after the period, only from make_walk(record_cpg=True)


def make_walk(engine: Engine, layout: Layout, params: ControllerParams, steps: int,
              feedback: FeedbackFn, record_qpos: bool = False, hand_steps: int = 0,
              record_cpg: bool = False) -> Callable:
    """A jitted ``walk(physics, controller_state, feedback_params) -> Trace`` over ``steps`` periods.

    ``feedback(obs, feedback_params)`` returns a_5 for one robot; it is ``vmap``-ed.
    ``record_qpos`` also keeps each period's full configuration (e.g. to render the gait),
    ``record_cpg`` the CPG's membrane states.
    ``hand_steps`` > 0: the hand-designed feedback acts for the first ``hand_steps`` periods,
    as at the start of a learning trial, and ``feedback`` from then on.
    """
    def one_robot_control(controller_state, sensors, fb_params, step):
        obs = observe(layout, sensors)
        action = after_hand_start(params, obs, feedback(obs, fb_params), step, hand_steps)
        controller_state, ctrl = control_step(params, layout, controller_state, obs, action)
        return controller_state, ctrl, obs, split_feedback(action)[0]

    def body(carry, step):
        physics, controller_state, fallen, fb_params = carry
        sensors = engine.sensors(physics)
        controller_state, ctrl, obs, a5 = jax.vmap(one_robot_control, (0, 0, 0, None))(controller_state, sensors, fb_params,
                                                                                 step)
        fallen = fallen | jax.vmap(lambda o: has_fallen(layout, o))(obs)
        physics = engine.step(physics, ctrl)
        trace = Trace(obs.height, obs.forward_position, obs.force_left, obs.force_right,
                      obs.roll, a5, fallen, obs.positive_work, sensors.qpos if record_qpos else None,
                      controller_state.cpg.z if record_cpg else None)
        return (physics, controller_state, fallen, fb_params), trace

    @xla.jit
    def walk(physics, controller_state, fb_params):
        batch = controller_state.ankle_pitch.shape[0]
        carry = (physics, controller_state, jnp.zeros(batch, bool), fb_params)
        _, trace = jax.lax.scan(body, carry, jnp.arange(steps))
        return jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), trace)

    return walk


def walk_from_standing(sim, feedback: FeedbackFn, fb_params, seconds: float,
                       record_qpos: bool = False, hand_seconds: float = 0.0, record_cpg: bool = False) -> Trace:
    """Robots on ``sim`` (a ``Simulation``), one per leading row of ``fb_params``, walk
    ``seconds`` from the standing pose in one batch; with ``hand_seconds`` > 0, the
    hand-designed feedback acts first for that long, as at a learning trial's start."""
    chex.assert_equal_shape_prefix(jax.tree.leaves(fb_params), 1)  # one row per robot, in every leaf
    batch = jax.tree.leaves(fb_params)[0].shape[0]
    run = make_walk(sim.engine, sim.layout, sim.params, round(seconds / sim.control_dt), feedback,
                    record_qpos, round(hand_seconds / sim.control_dt), record_cpg)
    return run(sim.engine.init(sim.qpos0, batch), initial_controller(batch), fb_params)


@dataclasses.dataclass
class GaitSummary:
    fell: bool
    seconds: float
    mean_vx: float
    mean_pelvis_height: float
    gait_period: float | None
    cost_of_transport: float | None

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


SETTLE_SECONDS = 2.0  # what ``summarise`` leaves out of a walk's start by default


def summarise(trace: Trace, control_dt: float, weight: float,
              settle_s: float = SETTLE_SECONDS) -> list[GaitSummary]:
    """Per robot: did it fall, simulated time before the fall, and, after ``settle_s`` and
    before any fall, the mean forward speed, the mean pelvis height, the gait period (a gait
    cycle is one period of the lateral sway: upward zero crossings of pelvis roll) and the
    cost of transport along +x (``weight``: m g, newtons)."""
    out = []
    for k in range(trace.height.shape[0]):
        fallen = np.asarray(trace.fallen[k])
        n = int(np.argmax(fallen)) if fallen.any() else len(fallen)
        start = min(int(settle_s / control_dt), max(n - 1, 0))
        x = np.asarray(trace.forward_position[k])
        h = np.asarray(trace.height[k])
        span = (n - 1 - start) * control_dt
        mean_vx = float((x[n - 1] - x[start]) / span) if span > 0 else 0.0
        period = sway_period(np.asarray(trace.roll[k])[start:n], control_dt)
        # The work read at a period's start is that of the period before it.
        work = float(np.sum(np.asarray(trace.positive_work[k])[start + 1:n], dtype=np.float64))
        out.append(GaitSummary(
            fell=bool(fallen.any()), seconds=n * control_dt, mean_vx=mean_vx,
            mean_pelvis_height=float(np.mean(h[start:n])) if n > start else float("nan"),
            gait_period=period,
            cost_of_transport=cost_of_transport(work, weight, float(x[n - 1] - x[start]))))
    return out


def cost_of_transport(positive_work: float, weight: float, distance: float) -> float | None:
    """CoT = positive actuator work / (m g distance), dimensionless (Collins et al., Science
    2005: about 0.2 for human walking, 3.2 for ASIMO); None unless the robot went forward."""
    return positive_work / (weight * distance) if distance > 0 else None


def sway_period(roll: np.ndarray, dt: float) -> float | None:
    """Mean interval between upward zero crossings of the mean-removed roll, or None."""
    if len(roll) < 3 or not np.all(np.isfinite(roll)):
        return None
    sway = roll - roll.mean()
    crossings = np.flatnonzero((sway[:-1] < 0) & (sway[1:] >= 0))
    return float(np.mean(np.diff(crossings)) * dt) if len(crossings) > 2 else None


def initial_controller(batch: int) -> ControllerState:
    """The controller's starting state (``controller.init_state``) for ``batch`` robots."""
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), init_state())
