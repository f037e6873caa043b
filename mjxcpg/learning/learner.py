"""One learner on one robot: the reward (eq 27), the trial protocol, and the actor-critic
step wired to the CPG controller.  Pure JAX for one learner; ``vmap`` it over learners.

A control step of one learner, in order:

1. observe the robot; the reward r = k_H (h1 - h') + k_S v_x (eq 27), with v_x low-pass
   filtered, since the instantaneous pelvis velocity swings negative with every lateral sway
   (with a commanded heading, v_x is the velocity along it: ``commanded_velocity``);
2. while the learner acts: the TD error (eq 17) of the last period and the weight updates
   (eqs 19, 22) with the traces as they were;
3. the action: during the first seconds of a trial the hand-designed a_5 = K d theta_roll/dt
   starts the gait; from a random hand-over time the policy's a_5 = a_max g(v) (eqs 10-12),
   and its traces take the new gradients (eqs 18, 21);
4. the CPG and the servo targets.

The reward's height and velocity and the fall test read the simulator's ground truth, or,
when ``Task.estimator`` is set, what the robot's own sensors give (``mjxcpg.control.estimator``: joint
angles, integrated gyro, sole forces, IMU tilt), as in the paper's online learning on hardware.

A trial ends at a fall (the robot is down, or its physics diverged) or after 20 s.  At a
fall the TD error is delta = r_fall - V(x(t - dt)), Doya's (2000) terminal condition: the
value just before the fall is pulled toward the fall's reward (-1), with no future after it
(divided by dt with ``LearnerParams.fall_impulse``).
Learning has succeeded after ``success_streak`` successive trials without a fall; the policy
goes on learning for ``TrialParams.trials_after_success`` more trials (or until the trial
budget ends), then stops with the weights as they were at the end of the newest streak of
``success_streak`` trials without a fall (learning on can also unlearn).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mjxcpg.control import estimator
from mjxcpg.control.controller import (ControllerParams, ControllerState, after_hand_start, control_step, hand_feedback,
                                      init_state, joint_targets, split_feedback)
from mjxcpg.control.walk import has_fallen
from mjxcpg.jaxutil.pytree import tree_where
from mjxcpg.learning import actor_critic as ac
from mjxcpg.learning import ngnet, policy
from mjxcpg.physics.model import Layout, Observation, Sensors, observe
from mjxcpg.robots.qrio import QRIO


ACTORS = ("policy", "zero", "hand")  # TrialParams.actor


@dataclasses.dataclass(frozen=True)
class TrialParams:
    """Reward (eq 27) and trial protocol (Experiments section)."""

    k_h: float = 10.0                     # height reward gain
    h_ref: float = QRIO.gait.h_ref        # h', m (the robot's: RobotDescription.gait)
    fall_reward: float = -1.0
    trial_seconds: float = 20.0
    hand_seconds: tuple[float, float] = (1.0, 3.0)  # hand-over time, uniform in this range
    velocity_filter_s: float = 0.5        # time constant of the v_x low-pass filter
    success_streak: int = 20
    max_trials: int = 1000
    # Trials the learner goes on learning after it first meets the success criterion (trials
    # to success still counts the first streak); 0 freezes the policy at success.
    trials_after_success: int = 0
    # What acts after the hand-over: "policy" (the learner), or a control that does not learn:
    # "zero" (a_5 = 0) or "hand" (the hand-designed feedback throughout).
    actor: str = "policy"

    @property
    def walk_hand_seconds(self) -> float:
        """How long the hand-designed feedback acts before a final policy is walked: the middle
        of the hand-over range, so that the policy takes over a gait already going, as in every
        trial it learned and was tested on."""
        return (self.hand_seconds[0] + self.hand_seconds[1]) / 2


class Bookkeeping(NamedTuple):
    trial: jax.Array              # trials finished
    step: jax.Array               # control steps into the current trial
    handover: jax.Array           # step at which the learner takes over
    trial_return: jax.Array       # accumulated reward of the current trial
    filtered_vx: jax.Array
    streak: jax.Array             # successive trials without a fall
    trials_to_success: jax.Array  # -1 until the success criterion is met
    returns: jax.Array            # (max_trials,) accumulated reward per trial
    falls: jax.Array              # (max_trials,) whether each trial ended in a fall
    # Diagnostics of the part of each trial after the hand-over (not used by the learner):
    acting_steps: jax.Array       # control periods acted in the current trial
    distance: jax.Array           # distance walked in them along the commanded heading (m; +x at 0)
    abs_a5_sum: jax.Array         # sum of |a_5| over them
    velocities: jax.Array         # (max_trials,) mean velocity along the commanded heading (m/s)
    mean_abs_a5: jax.Array        # (max_trials,) mean |a_5|
    sigmas: jax.Array             # (max_trials,) the policy's sigma at the trial's end


class LearnerState(NamedTuple):
    k_s: jax.Array
    key: jax.Array                # the learner's random stream (``period_draws``)
    period: jax.Array             # control periods since the run started
    controller: ControllerState
    weights: ac.Weights
    traces: ac.Traces
    previous_basis: jax.Array     # b(x(t - dt)); V(t - dt) is re-evaluated with current weights
    has_previous: jax.Array
    noise: jax.Array              # the exploration noise n(t - dt) of the last action (0 before the first)
    kept: ac.Weights              # the weights at the end of the newest streak of success_streak fall-free trials
    book: Bookkeeping
    estimate: estimator.EstimatorState | None = None  # only with Task.estimator (no leaves otherwise)
    k_e: jax.Array | None = None  # energy reward gain (``reward``); None: none, the paper's reward


@dataclasses.dataclass(frozen=True)
class Task:
    """Everything static a learner step needs."""

    layout: Layout
    controller: ControllerParams
    learner: ac.LearnerParams
    trial: TrialParams
    basis: ngnet.NGnetBasis
    # Where the reward's height and velocity and the fall test come from: None, the simulator's
    # ground truth; otherwise estimated from the robot's sensors with these constants.
    estimator: estimator.EstimatorParams | None = None

    @property
    def dt(self) -> float:
        return self.controller.control_dt

    @property
    def trial_steps(self) -> int:
        return round(self.trial.trial_seconds / self.dt)


def reward(trial: TrialParams, k_s: jax.Array, height: jax.Array, forward_velocity: jax.Array,
           k_e: jax.Array | None = None, power_per_weight: jax.Array | float = 0.0) -> jax.Array:
    """Eq (27): r = k_H (h1 - h') + k_S v_x; with an energy gain ``k_e`` the energy term in
    the same form, r = k_H (h1 - h') + k_S v_x - k_E P / (m g), ``power_per_weight`` being
    P / (m g) (m/s), P the actuators' positive mechanical power: over a walk at speed v the
    term's mean is k_E times the cost of transport times v."""
    r = trial.k_h * (height - trial.h_ref) + k_s * forward_velocity
    if k_e is not None:  # None (a run without energy gains): the paper's reward, bit for bit
        r = r - k_e * power_per_weight
    return r


def policy_input(obs: Observation) -> jax.Array:
    """x = (d theta_roll/dt, d theta_pitch/dt), the pelvis gyro; zeros if it is not finite."""
    x = obs.gyro[:2]
    return jnp.where(jnp.isfinite(x), x, 0.0)


class Draws(NamedTuple):
    """The random numbers of one control period of one learner."""

    noise: jax.Array     # n ~ N(0, 1) of eq (12), the policy's exploration
    handover: jax.Array  # uniform in [0, 1): the next trial's hand-over time, if this one ends


def period_draws(key: jax.Array, period: jax.Array, outputs: int = 1) -> Draws:
    """The draws of control period ``period`` of the learner whose stream is ``key``: one
    noise per policy output (``LearnerParams.outputs``; shape () for one).

    They depend on the period's index alone, so ``train.make_chunk`` draws a whole chunk's at
    once, outside its loop over periods (a draw costs several small XLA loops, which add up
    when repeated every 8 ms), and a run cut into other chunks, or resumed, draws the same.
    """
    noise_key, handover_key = jax.random.split(jax.random.fold_in(key, period))
    return Draws(noise=jax.random.normal(noise_key, ac.output_shape(outputs)),
                 handover=jax.random.uniform(handover_key))


def _handover_step(task: Task, uniform: jax.Array) -> jax.Array:
    low, high = task.trial.hand_seconds
    return jnp.round((low + (high - low) * uniform) / task.dt).astype(jnp.int32)


def init_learner(task: Task, k_s: float, seed: int, k_e: float | None = None) -> LearnerState:
    key, sub = jax.random.split(jax.random.PRNGKey(seed))
    k = task.basis.centers.shape[0]
    n = task.trial.max_trials
    return LearnerState(
        k_s=jnp.float32(k_s), key=key, period=jnp.int32(0), controller=init_state(),
        weights=ac.init_weights(task.learner, k), traces=ac.init_traces(k, task.learner.outputs),
        previous_basis=jnp.zeros(k, jnp.float32), has_previous=jnp.bool_(False),
        noise=jnp.zeros(ac.output_shape(task.learner.outputs), jnp.float32),
        kept=ac.init_weights(task.learner, k), book=Bookkeeping(
            trial=jnp.int32(0), step=jnp.int32(0), handover=_handover_step(task, jax.random.uniform(sub)),
            trial_return=jnp.float32(0), filtered_vx=jnp.float32(0), streak=jnp.int32(0),
            trials_to_success=jnp.int32(-1), returns=jnp.zeros(n, jnp.float32),
            falls=jnp.zeros(n, bool), acting_steps=jnp.int32(0), distance=jnp.float32(0),
            abs_a5_sum=jnp.float32(0), velocities=jnp.zeros(n, jnp.float32),
            mean_abs_a5=jnp.zeros(n, jnp.float32), sigmas=jnp.zeros(n, jnp.float32)),
        estimate=_initial_estimate(task), k_e=None if k_e is None else jnp.float32(k_e),
    )


def _initial_estimate(task: Task) -> estimator.EstimatorState | None:
    if task.estimator is None:
        return None
    return estimator.init_state(task.estimator, task.layout.pelvis_height(task.controller.z0))


def commanded_velocity(params: ControllerParams, obs: Observation) -> jax.Array:
    """The velocity the reward's k_S term reads: the pelvis' along the commanded heading c
    (``ControllerParams.heading_command``), v_x cos c + v_y sin c; at c = 0, v_x itself, the
    paper's eq (27)."""
    if params.heading_command == 0.0:
        return obs.forward_velocity
    c = params.heading_command
    return obs.forward_velocity * math.cos(c) + obs.lateral_velocity * math.sin(c)


def measured_inputs(task: Task, state: LearnerState, sensors: Sensors, obs: Observation):
    """(height, forward velocity, fell, estimator state) for the reward and the fall test:
    the ground truth (the velocity along the commanded heading, ``commanded_velocity``), or
    the estimator's reading of the sensors when ``task.estimator`` is set (its velocity is
    along the robot's own heading, which the heading reflex holds at the command)."""
    if task.estimator is None:
        return obs.height, commanded_velocity(task.controller, obs), has_fallen(task.layout, obs), state.estimate
    estimate_state, measured = estimator.estimate(task.estimator, state.estimate, sensors, obs, task.dt)
    return measured.height, measured.forward_velocity, measured.fallen, estimate_state


def is_done(task: Task, state: LearnerState) -> jax.Array:
    """Succeeded and ``trials_after_success`` trials past it, or out of trials."""
    book = state.book
    learned_past_success = (book.trials_to_success >= 0) & (
        book.trial >= book.trials_to_success + task.trial.trials_after_success)
    return learned_past_success | (book.trial >= task.trial.max_trials)


def learner_step(task: Task, state: LearnerState, sensors: Sensors, home_ctrl: jax.Array,
                 draws: Draws) -> tuple[LearnerState, jax.Array, jax.Array]:
    """One control period of one learner, with that period's ``period_draws``: returns
    (state, servo targets, trial ended)."""
    p, book = task.learner, state.book
    obs = observe(task.layout, sensors)
    height, forward_velocity, fell, estimate_state = measured_inputs(task, state, sensors, obs)
    alpha = task.dt / task.trial.velocity_filter_s
    filtered_vx = book.filtered_vx + alpha * (jnp.nan_to_num(forward_velocity) - book.filtered_vx)
    r = reward(task.trial, state.k_s, height, filtered_vx, state.k_e,
               obs.positive_work / (task.dt * task.layout.weight))

    frozen = is_done(task, state)
    acting = book.step >= book.handover
    b = ngnet.normalized_basis(task.basis, policy_input(obs))
    previous_value = ngnet.ngnet_value(state.weights.critic, state.previous_basis)
    delta = jnp.where(
        fell, ac.terminal_td_error(task.trial.fall_reward, previous_value, task.dt, p.fall_impulse),
        ac.td_error(r, ngnet.ngnet_value(state.weights.critic, b), previous_value, task.dt, p.tau))
    update = acting & state.has_previous & ~frozen & (task.trial.actor == "policy")
    weights = tree_where(update, ac.learner_update(p, state.weights, state.traces, delta, task.dt, fell),
                         state.weights)

    mean = ngnet.ngnet_value(weights.mean, b)
    std = ngnet.policy_std(weights.sigma)
    noise = policy.exploration_noise(state.noise, draws.noise, policy.noise_decay(p.noise_correlation_s, task.dt))
    v = policy.sample_action(mean, std, noise)
    hand = hand_feedback(task.controller, obs)
    after_handover = {"policy": p.action(v), "zero": jnp.zeros_like(hand), "hand": hand}
    action = after_hand_start(task.controller, obs, after_handover[task.trial.actor], book.step, book.handover)
    a5 = split_feedback(action)[0]
    previous_b = jnp.where(state.has_previous, state.previous_basis, 0.0)  # b_{t-1}, 0 at the first action
    traces = tree_where(acting, ac.accumulate_traces(p, state.traces, b, v, mean, std, task.dt,
                                                     state.noise, previous_b), state.traces)
    controller_state, ctrl = control_step(task.controller, task.layout, state.controller, obs, action)

    trial_return = book.trial_return + jnp.where(
        acting, jnp.where(fell, task.trial.fall_reward, r * task.dt), 0.0)
    ended = fell | (book.step + 1 >= task.trial_steps)
    record = ended & ~frozen
    index = jnp.minimum(book.trial, task.trial.max_trials - 1)
    streak = jnp.where(ended, jnp.where(fell, 0, book.streak + 1), book.streak)
    newly_succeeded = record & (streak >= task.trial.success_streak) & (book.trials_to_success < 0)
    acting_steps = book.acting_steps + acting.astype(jnp.int32)
    along_command = jnp.nan_to_num(commanded_velocity(task.controller, obs))
    distance = book.distance + jnp.where(acting, along_command * task.dt, 0.0)
    abs_a5_sum = book.abs_a5_sum + jnp.where(acting, jnp.abs(a5), 0.0)
    acted = jnp.maximum(acting_steps, 1)

    def per_trial(history: jax.Array, value: jax.Array) -> jax.Array:
        return history.at[index].set(jnp.where(record, value, history[index]))
    book = Bookkeeping(
        trial=book.trial + record.astype(jnp.int32),
        step=jnp.where(ended, 0, book.step + 1),
        handover=jnp.where(ended, _handover_step(task, draws.handover), book.handover),
        trial_return=jnp.where(ended, 0.0, trial_return),
        filtered_vx=jnp.where(ended, 0.0, filtered_vx),
        streak=streak,
        trials_to_success=jnp.where(newly_succeeded, book.trial + 1, book.trials_to_success),
        returns=per_trial(book.returns, trial_return),
        falls=per_trial(book.falls, fell),
        acting_steps=jnp.where(ended, 0, acting_steps),
        distance=jnp.where(ended, 0.0, distance),
        abs_a5_sum=jnp.where(ended, 0.0, abs_a5_sum),
        velocities=per_trial(book.velocities, distance / (acted * task.dt)),
        mean_abs_a5=per_trial(book.mean_abs_a5, abs_a5_sum / acted),
        sigmas=per_trial(book.sigmas, ngnet.policy_std(p.propulsive_sigma(weights.sigma))),
    )
    kept = tree_where(record & ~fell & (streak >= task.trial.success_streak), weights, state.kept)
    # The step that ends learning hands over the kept weights: the final policy passed the test.
    stops = record & (book.trials_to_success >= 0) & is_done(task, state._replace(book=book))
    weights = tree_where(stops, kept, weights)
    state = LearnerState(
        k_s=state.k_s, key=state.key, period=state.period + 1,
        controller=tree_where(ended, init_state(), controller_state),
        weights=weights,
        traces=tree_where(ended, ac.init_traces(b.shape[0], p.outputs), traces),
        previous_basis=b, has_previous=acting & ~ended,
        noise=jnp.where(acting & ~ended, noise, 0.0), kept=kept, book=book,
        estimate=tree_where(ended, _initial_estimate(task), estimate_state), k_e=state.k_e,
    )
    return state, jnp.where(ended, home_ctrl, ctrl), ended


def home_ctrl(task: Task) -> jax.Array:
    """Servo targets of the standing pose that every trial starts from."""
    return joint_targets(task.controller, task.layout, jnp.zeros(6))


def actor_feedback(task: Task):
    """a_5 of what acts after the hand-over, without exploration noise: the learned policy's
    mean (``policy_mean_feedback``), or a control's 0 or hand-designed feedback."""
    if task.trial.actor == "zero":
        return lambda obs, weights: jnp.zeros_like(obs.gyro[0])
    if task.trial.actor == "hand":
        return lambda obs, weights: hand_feedback(task.controller, obs)
    return policy_mean_feedback(task)


def policy_mean_feedback(task: Task):
    """The learned policy's feedback without noise, for walking and evaluation:
    ``feedback(obs, weights)`` = a_max g(mu(x) / v_scale), a_5 (and the stepping feedback with
    two outputs: ``LearnerParams.action``)."""
    def feedback(obs: Observation, weights: ac.Weights) -> jax.Array:
        b = ngnet.normalized_basis(task.basis, policy_input(obs))
        return task.learner.action(ngnet.ngnet_value(weights.mean, b))
    return feedback
