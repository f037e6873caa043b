"""The learner's trial protocol, driven by scripted sensor readings (no physics): the
hand-designed phase, the TD error at a fall, the trial return, the velocity filter, the
traces between trials, and the success streak.  Every expectation is derived by hand from
the reward (eq 27), the TD error at a fall and the update rule (eq 19), not read back from
the learner."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxcpg.control.controller import ControllerParams
from mjxcpg.learning import actor_critic as ac
from mjxcpg.learning import ngnet
from mjxcpg.learning.learner import Draws, TrialParams, Task, home_ctrl, init_learner, is_done, learner_step
from mjxcpg.physics.model import Layout, Sensors, load_model

DT = 0.008
HANDOVER_STEP = 3                   # hand_seconds = (0.024, 0.024): the learner acts from step 3
TRIAL_STEPS = 10                    # trial_seconds = 0.08
STANDING = 0.28                     # m: pelvis height while walking (falls below 0.20)
FALLEN = 0.10
K_S = 2.0


def make_task(learner: ac.LearnerParams = ac.LearnerParams(), **trial) -> Task:
    layout = Layout.of(load_model())
    defaults = dict(trial_seconds=TRIAL_STEPS * DT, hand_seconds=(HANDOVER_STEP * DT,) * 2,
                    success_streak=2, max_trials=8)
    return Task(layout=layout, controller=ControllerParams(), learner=learner,
                trial=TrialParams(**(defaults | trial)), basis=ngnet.make_basis())


def sensors(layout: Layout, height: float, forward_velocity: float, roll_rate: float = 0.3) -> Sensors:
    """An upright robot at ``height`` moving forward at ``forward_velocity``."""
    model = load_model()
    qpos = np.zeros(model.nq, np.float32)
    qpos[2], qpos[3] = height, 1.0
    qvel = np.zeros(model.nv, np.float32)
    qvel[0] = forward_velocity
    data = np.zeros(model.nsensordata, np.float32)
    data[layout.quat] = 1.0
    data[layout.gyro] = roll_rate
    return Sensors(jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(data), jnp.float32(0.0))


class Script:
    """Steps one learner through scripted readings with a fixed exploration draw (0: none)."""

    def __init__(self, task: Task, k_s: float = K_S, critic: float = 0.0, noise: float = 0.0):
        self.noise = jnp.float32(noise)
        self.task = task
        self.state = init_learner(task, k_s, seed=0)
        weights = self.state.weights._replace(critic=jnp.full_like(self.state.weights.critic, critic))
        self.state = self.state._replace(weights=weights)
        self.step = jax.jit(functools.partial(learner_step, task))
        self.home = home_ctrl(task)

    def run(self, readings: Sensors, steps: int = 1) -> list[bool]:
        ended = []
        for _ in range(steps):
            self.state, _, end = self.step(self.state, readings, self.home, Draws(self.noise, jnp.float32(0)))
            ended.append(bool(end))
        return ended


@pytest.fixture(scope="module")
def task():
    return make_task()


def test_no_weight_update_in_the_hand_designed_phase(task):
    """The hand-designed feedback acts for the first steps; the learner's weights stay as
    initialised until it acts, and its first acting step (no previous state, zero traces)
    changes nothing either."""
    script = Script(task, critic=0.5)
    walking = sensors(task.layout, STANDING, 0.1)
    initial = script.state.weights
    for _ in range(HANDOVER_STEP + 1):
        script.run(walking)
        for leaf, start in zip(script.state.weights, initial):
            np.testing.assert_array_equal(leaf, start)
    script.run(walking)  # the second acting step updates
    assert not np.array_equal(script.state.weights.critic, initial.critic)


def test_trial_return_and_velocity_filter(task):
    """A full trial without a fall at a constant height and velocity: the filtered velocity
    starts from 0 each trial, v_f(n) = v (1 - (1 - a)^(n+1)) with a = dt / 0.5 s at step n
    (0-based), and the return sums r dt = (k_H (h - h') + k_S v_f) dt over the acting steps
    HANDOVER_STEP .. TRIAL_STEPS - 1.  The second trial starts from v_f = 0 again."""
    script = Script(task)
    height, velocity = 0.283, 0.05
    ended = script.run(sensors(task.layout, height, velocity), TRIAL_STEPS)
    assert ended == [False] * (TRIAL_STEPS - 1) + [True]
    a = DT / task.trial.velocity_filter_s
    filtered = velocity * (1 - (1 - a) ** (np.arange(TRIAL_STEPS) + 1))
    rewards = task.trial.k_h * (height - task.trial.h_ref) + K_S * filtered
    expected = rewards[HANDOVER_STEP:].sum() * DT
    book = script.state.book
    assert int(book.trial) == 1 and not bool(book.falls[0])
    np.testing.assert_allclose(float(book.returns[0]), expected, rtol=1e-5)
    assert float(book.filtered_vx) == 0.0 and float(book.trial_return) == 0.0
    np.testing.assert_allclose(float(book.velocities[0]), velocity, rtol=1e-6)
    script.run(sensors(task.layout, height, velocity), TRIAL_STEPS)
    np.testing.assert_allclose(float(script.state.book.returns[1]), expected, rtol=1e-5)


def test_fall_ends_the_trial_with_the_terminal_td_error(task):
    """A fall at step n: the trial ends, its return gains the fall reward -1 (not -1 dt), and
    the critic moves by alpha' delta e^c dt with delta = -1 - V(x(t - dt)) (nothing follows a
    fall).  With every critic weight c, V = c everywhere (the normalized basis sums to 1)."""
    critic = 0.4
    script = Script(task, critic=critic)
    walking = sensors(task.layout, STANDING, 0.0)
    script.run(walking, HANDOVER_STEP + 3)
    before = script.state
    ended = script.run(sensors(task.layout, FALLEN, 0.0))
    assert ended == [True]
    delta = -1.0 - critic
    p = task.learner
    expected_critic = before.weights.critic + p.rate_scale * p.alpha * delta * before.traces.critic * DT
    np.testing.assert_allclose(script.state.weights.critic, expected_critic, rtol=1e-5, atol=1e-7)
    book = script.state.book
    assert int(book.trial) == 1 and bool(book.falls[0]) and int(book.streak) == 0
    rewards_before_fall = (task.trial.k_h * (STANDING - task.trial.h_ref)) * 3 * DT  # v = 0: height term only
    np.testing.assert_allclose(float(book.returns[0]), rewards_before_fall - 1.0, rtol=1e-5)


def test_traces_and_noise_reset_between_trials():
    """With correlated noise (a = exp(-dt / 0.2 s)) and the draw xi = 1 every period, the noise
    after k acting periods is sqrt(1 - a^2) (1 + a + ... + a^(k-1)); a trial's end resets it
    and the traces to 0."""
    task = make_task(ac.LearnerParams(noise_correlation_s=0.2))
    script = Script(task, noise=1.0)
    script.run(sensors(task.layout, STANDING, 0.1), HANDOVER_STEP + 3)
    a = math.exp(-DT / 0.2)
    np.testing.assert_allclose(float(script.state.noise), math.sqrt(1 - a * a) * (1 + a + a * a), rtol=1e-5)
    assert float(jnp.abs(script.state.traces.critic).sum()) > 0
    script.run(sensors(task.layout, FALLEN, 0.1))
    for trace in script.state.traces:
        np.testing.assert_array_equal(trace, 0.0)
    assert float(script.state.noise) == 0.0 and not bool(script.state.has_previous)


def test_success_streak_then_learning_continues_then_freezes():
    """success_streak = 2 fall-free trials after one fall: trials to success is 3 (the first
    streak, counted from 1); with trials_after_success = 2 the learner goes on learning in
    trials 4 and 5 and is done after trial 5, its weights frozen from then on."""
    task = make_task(trials_after_success=2)
    script = Script(task, critic=0.2)
    walking, fallen = sensors(task.layout, STANDING, 0.05), sensors(task.layout, FALLEN, 0.0)
    script.run(walking, HANDOVER_STEP + 2)
    script.run(fallen)
    script.run(walking, 2 * TRIAL_STEPS)
    book = script.state.book
    assert int(book.trial) == 3 and int(book.trials_to_success) == 3
    assert not bool(is_done(task, script.state))
    at_success = script.state.weights
    script.run(walking, 2 * TRIAL_STEPS)
    assert int(script.state.book.trial) == 5 and bool(is_done(task, script.state))
    assert not np.array_equal(script.state.weights.critic, at_success.critic)   # learned after success
    assert int(script.state.book.trials_to_success) == 3                        # still the first streak
    frozen = script.state.weights
    script.run(walking, TRIAL_STEPS)
    assert int(script.state.book.trial) == 5                                     # nothing more recorded
    np.testing.assert_array_equal(script.state.weights.critic, frozen.critic)


def test_policy_freezes_at_success_by_default():
    task = make_task()
    script = Script(task, critic=0.2)
    script.run(sensors(task.layout, STANDING, 0.05), 2 * TRIAL_STEPS)
    assert int(script.state.book.trials_to_success) == 2 and bool(is_done(task, script.state))
    frozen = script.state.weights
    script.run(sensors(task.layout, STANDING, 0.05), TRIAL_STEPS)
    np.testing.assert_array_equal(script.state.weights.critic, frozen.critic)


def assert_ends_with_weights_of_success(task: Task) -> None:
    """Two fall-free trials (success), a third that falls, a fourth without a fall: learning
    has stopped after trial 4 and the weights are those at the end of trial 2."""
    script = Script(task, critic=0.2)
    walking, fallen = sensors(task.layout, STANDING, 0.05), sensors(task.layout, FALLEN, 0.0)
    script.run(walking, 2 * TRIAL_STEPS)
    at_success = script.state.weights
    assert int(script.state.book.trials_to_success) == 2
    script.run(walking, HANDOVER_STEP + 2)
    script.run(fallen)
    script.run(walking, TRIAL_STEPS)
    assert int(script.state.book.trial) == 4 and bool(is_done(task, script.state))
    for final, kept in zip(script.state.weights, at_success):
        np.testing.assert_array_equal(final, kept)


def test_budget_end_after_success_also_ends_with_the_kept_policy():
    """success_streak = 2, trials_after_success = 5, max_trials = 4: success after trials 1-2,
    trial 3 falls, trial 4 ends the budget; the run ends with the weights of trial 2's end."""
    task = make_task(trials_after_success=5, max_trials=4)
    assert_ends_with_weights_of_success(task)


def test_learning_on_ends_with_the_last_policy_that_passed_the_test():
    """success_streak = 2: success after trials 1-2; trial 3 falls, trial 4 does not, and
    learning stops after trial 4 (trials_after_success = 2).  The last policy whose previous
    2 trials had no fall is the one at the end of trial 2: the run ends with it."""
    task = make_task(trials_after_success=2)
    assert_ends_with_weights_of_success(task)
