"""What a run reports while it runs: TensorBoard event files (read back with TensorBoard's own
reader) and the estimate of the time left."""

import dataclasses
import math
from collections import Counter
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tensorboard.backend.event_processing.event_file_loader import RawEventFileLoader
from tensorboard.compat.proto.event_pb2 import Event

from mjxcpg.learning.learner import TrialParams
from mjxcpg.training import train
from mjxcpg.training.events import RunEvents, read_scalars
from mjxcpg.training.progress import (RunProgress, compile_seconds_left, cost_model, history_fall_rate,
                                      lindy_mean, pareto_draws, recent_fall_rate, remaining_seconds_simulated,
                                      sampled_total_trials, trials_to_streak, wall_seconds_left)
from mjxcpg.training.train import AheadOfTime


def tensorboard_scalars(directory: Path) -> dict[str, list[tuple[int, float]]]:
    """tag -> every (step, value) of the event files in ``directory``, duplicates kept."""
    found: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(directory.glob("events.out.tfevents.*")):
        for record in RawEventFileLoader(str(path)).Load():
            event = Event.FromString(record)
            for value in event.summary.value:
                found.setdefault(value.tag, []).append((event.step, value.simple_value))
    return found


class Book(NamedTuple):
    """The per-trial part of ``learner.Bookkeeping`` that the events read."""

    trial: np.ndarray
    returns: np.ndarray
    falls: np.ndarray
    velocities: np.ndarray
    mean_abs_a5: np.ndarray
    sigmas: np.ndarray


def _book(trials: list[int], budget: int = 6) -> Book:
    ramp = np.arange(len(trials) * budget, dtype=np.float32).reshape(len(trials), budget)
    return Book(trial=np.array(trials), returns=ramp, falls=(ramp % 2 == 1), velocities=ramp / 100,
                mean_abs_a5=ramp / 10, sigmas=0.5 - ramp / 1000)


def test_events_of_a_resumed_run_hold_every_trial_once(tmp_path):
    first = RunEvents(tmp_path, k_s=(10.0, 0.0), seeds=(0, 1))
    first.write_trials(_book([2, 3]), done=np.array([False, False]))
    first.write_progress(5, {"trials_per_s": 2.0})
    first.close()
    # a resumed session recomputes from an older checkpoint (1 and 2 trials), then goes on
    again = RunEvents(tmp_path, k_s=(10.0, 0.0), seeds=(0, 1))
    again.write_trials(_book([1, 2]), done=np.array([False, False]))
    again.write_progress(3, {"trials_per_s": 9.0})
    again.write_trials(_book([4, 3]), done=np.array([True, False]))
    again.write_progress(7, {"trials_per_s": 3.0})
    again.close()
    book = _book([4, 3])
    for learner, name in enumerate(("learner_00_ks10_seed0", "learner_01_ks0_seed1")):
        scalars = tensorboard_scalars(tmp_path / "tensorboard" / name)
        trials = int(book.trial[learner])
        assert [step for step, _ in scalars["trial/return"]] == list(range(1, trials + 1))
        assert [v for _, v in scalars["trial/return"]] == list(book.returns[learner][:trials])
        assert [v for _, v in scalars["trial/fell"]] == [float(f) for f in book.falls[learner][:trials]]
        assert [v for _, v in scalars["trial/sigma"]] == pytest.approx(book.sigmas[learner][:trials])
        assert Counter(step for step, _ in scalars["trial/mean_vx"]) == Counter(range(1, trials + 1))
    assert tensorboard_scalars(tmp_path / "tensorboard" / "run")["progress/trials_per_s"] == [(5, 2.0), (7, 3.0)]


def test_a_record_cut_short_ends_its_file(tmp_path):
    events = RunEvents(tmp_path, k_s=(1.0,), seeds=(0,))
    events.write_trials(_book([3]), done=np.array([False]))
    events.close()
    [path] = (tmp_path / "tensorboard" / "learner_00_ks1_seed0").glob("events.*")
    path.write_bytes(path.read_bytes()[:-7])  # the last trial's record, torn by a kill
    assert sorted(read_scalars(path.parent)["trial/return"]) == [1, 2]


TRIAL = TrialParams(max_trials=100, trial_seconds=20.0, success_streak=20, trials_after_success=5)


DRAWS = 100_000


def totals(trials, streak, tts, done, k_s=None, fall_rate=None, trial=TRIAL, draws=DRAWS):
    """``sampled_total_trials`` of learners given as lists, from a fixed seed."""
    trials = np.array(trials)
    return sampled_total_trials(trial, np.zeros(len(trials)) if k_s is None else np.array(k_s), trials,
                                np.array(streak), np.array(tts), np.array(done), draws,
                                np.random.default_rng(1), None if fall_rate is None else np.array(fall_rate))


def test_sampled_totals_come_from_longer_peers_or_are_exact():
    drawn = totals(trials=[60, 90, 40, 30, 30, 10], streak=[0, 0, 0, 3, 18, 0], tts=[-1, 85, 35, -1, -1, 4],
                   done=[False, True, True, False, False, False], k_s=[0.0, 0.0, 10.0, 10.0, 0.0, 10.0], draws=50)
    assert (drawn[:, 1] == 90).all() and (drawn[:, 2] == 40).all()   # finished: their totals
    assert (drawn[:, 0] == 90).all()                 # the finished k_s = 0 learner that ran longer
    # the finished k_s = 10 learner that ran longer says 40, but the 17 fall-free trials it
    # still needs and the 5 after them come first
    assert (drawn[:, 3] == 30 + 17 + 5).all()
    assert (drawn[:, 4] == 90).all()                 # as learner 0
    assert (drawn[:, 5] == 4 + 5).all()              # succeeded: exact
    # two longer peers of its k_s: each drawn, about half the time (50 draws: 25 +- 3.5)
    mixed = totals(trials=[10, 50, 80], streak=[0, 0, 0], tts=[-1, -1, -1], done=[False, True, True], draws=50)
    assert set(mixed[:, 0]) == {50, 80} and 10 <= np.sum(mixed[:, 0] == 50) <= 40


def test_lindy_mean_is_the_mean_of_the_capped_pareto_tail():
    """E[min(T, B)] for P(T > x) = t / x (x >= t) is t + the integral of t / x from t to B,
    here summed numerically."""
    t, budget = 30.0, 100.0
    x = np.linspace(t, budget, 200_001)
    assert lindy_mean(t, budget) == pytest.approx(t + np.trapezoid(t / x, x), rel=1e-6)
    assert lindy_mean(0, budget) == 0 and lindy_mean(150, budget) == budget


def test_pareto_draws_have_lindys_mean():
    """min(T, B) lies in [t, B], so its standard deviation is below (B - t) / 2 = 35 and the
    mean of 100,000 draws is within 6 standard errors, 0.66 trial, of ``lindy_mean``."""
    draws = pareto_draws(30.0, 100.0, np.random.default_rng(0).random(DRAWS))
    assert draws.min() >= 30 and draws.max() == 100
    assert draws.mean() == pytest.approx(lindy_mean(30.0, 100.0), abs=0.66)
    assert (pareto_draws(0.0, 100.0, np.random.default_rng(0).random(5)) == 0).all()


def test_totals_without_longer_peers_follow_lindys_law_within_the_budget():
    drawn = totals(trials=[10, 30, 70], streak=[0, 19, 15], tts=[-1, -1, -1], done=[True, False, False])
    # learner 1: T + 5 within the budget of 100 is min(T, 95) + 5, of mean lindy_mean(30, 95) + 5
    # (its one fall-free trial still needed lifts draws below 31 by under one trial: 1/31 of
    # them, under 0.04 on the mean); within 0.66 trial, as ``test_pareto_draws_have_lindys_mean``
    assert drawn[:, 1].mean() == pytest.approx(30 * (1 + math.log(95 / 30)) + 5, abs=0.66)
    assert drawn[:, 2].max() == 100               # the budget, though 70 + 5 trials could exceed it
    # never fewer than the fall-free streak (and the trials after it) still needed
    short = totals(trials=[3, 4], streak=[0, 1], tts=[-1, -1], done=[False, False])
    assert short[:, 1].min() == 4 + 19 + 5


def test_a_learners_draws_do_not_move_when_another_succeeds():
    before = totals(trials=[100, 120, 150], streak=[0, 0, 0], tts=[-1, -1, -1], done=[False] * 3, draws=256)
    after = totals(trials=[100, 120, 150], streak=[0, 0, 0], tts=[90, -1, -1], done=[False] * 3, draws=256)
    assert (after[:, 0] == 90 + 5).all()
    np.testing.assert_array_equal(after[:, 1:], before[:, 1:])


def test_the_slowest_of_several_learners_needs_more_than_one_on_average():
    """Two learners at t = 100 trials under Lindy's law within B = 1000: the slower one's
    mean total is t plus the integral of 1 - (1 - t/x)^2 over [t, B], 2 t ln(B / t) + t^2 / B =
    470.5, against 330.3 for either (``lindy_mean``).  Draws below t + 1 are lifted to the one
    fall-free trial still needed (probability 1/101, at most 1 trial: under 0.01 on the mean);
    the maximum's standard deviation is under 450, so 100,000 draws are within 6 standard
    errors, 8.5 trials."""
    one_trial_streak = TrialParams(max_trials=1000, trial_seconds=20.0, success_streak=1, trials_after_success=0)
    drawn = totals(trials=[100, 100], streak=[0, 0], tts=[-1, -1], done=[False, False], trial=one_trial_streak)
    assert drawn.max(axis=1).mean() == pytest.approx(2 * 100 * math.log(10) + 100 ** 2 / 1000, abs=8.5)
    assert drawn.mean(axis=0) == pytest.approx([lindy_mean(100, 1000)] * 2, abs=8.5)


def test_trials_to_streak_is_the_waiting_time_for_a_run_of_successes():
    # two heads in a row with a fair coin: 6 tosses on average, 4 after a first head
    assert trials_to_streak(0.5, 0, 2) == pytest.approx(6.0)
    assert trials_to_streak(0.5, 1, 2) == pytest.approx(4.0)
    assert trials_to_streak(0.0, 5, 20) == 15 and trials_to_streak(0.3, 20, 20) == 0
    # against simulated learners that fall with probability 0.1 per trial: the mean of 20,000
    # waits (standard deviation about 60 trials) has a standard error of about 0.5 trial
    rng = np.random.default_rng(0)
    waits = []
    for _ in range(20_000):
        n = streak = 0
        while streak < 20:
            n += 1
            streak = 0 if rng.random() < 0.1 else streak + 1
        waits.append(n)
    assert trials_to_streak(0.1, 0, 20) == pytest.approx(np.mean(waits), abs=2.5)   # (0.9^-20 - 1) / 0.1 = 72.3


def test_recent_fall_rate_counts_the_last_trials_with_laplaces_rule():
    falls = np.zeros((2, 100), bool)
    falls[0, [0, 3]] = True
    falls[1, :10] = True                     # falls only before its last 50 trials
    rates = recent_fall_rate(falls, np.array([4, 60]))
    assert rates.tolist() == pytest.approx([(2 + 1) / (4 + 2), 1 / 52])


def test_history_fall_rate_waits_as_the_windows_complete_streaks():
    falls = np.zeros((4, 200), bool)
    falls[0, :100:5] = True         # 10 falls in each of its 2 windows of 50
    falls[1, 50:100] = True         # its newest window falls every time, the one before never
    falls[2, :10] = True            # 60 trials: the newest 50 without a fall, the 10 before all falls
    rates = history_fall_rate(falls, np.array([100, 100, 60, 0]), 20)
    # every window at Laplace's 11/52: that rate
    assert rates[0] == pytest.approx(11 / 52)
    # a window at 1/52 completes a streak every T = ((51/52)^-20 - 1) / (1/52) = 24.6 trials,
    # the other at 51/52 one in about 52^20 (nothing); over both windows, 100 trials, one
    # completion in 2T: the wait at the rate found is 2T
    t_clean = ((51 / 52) ** -20 - 1) / (1 / 52)
    assert trials_to_streak(rates[1], 0, 20) == pytest.approx(2 * t_clean, rel=1e-9)
    # windows back from the newest: 50 trials at 1/52 and 10 at 11/12 (nothing), so 60 / (50 / T)
    assert trials_to_streak(rates[2], 0, 20) == pytest.approx(60 / 50 * t_clean, rel=1e-9)
    assert rates[3] == 1.0          # no trial yet: no bound


def test_a_learner_that_rarely_falls_is_expected_to_finish_sooner_than_lindys_law_says():
    trials, streak, tts, done = [60, 60], [5, 5], [-1, -1], [False, False]
    lindy = totals(trials, streak, tts, done)
    bounded = totals(trials, streak, tts, done, fall_rate=[0.02, 0.9])
    # fall rate 0.02: (0.98^-20 - 0.98^-5) / 0.02 = 19.6 more trials to the streak, then 5;
    # Lindy's draws above that are brought down to it
    bound = 60 + (0.98 ** -20 - 0.98 ** -5) / 0.02 + 5
    assert bounded[:, 0].max() == pytest.approx(bound)
    np.testing.assert_allclose(bounded[:, 0], np.minimum(lindy[:, 0], bound), rtol=1e-12)
    np.testing.assert_allclose(bounded[:, 1], lindy[:, 1], rtol=1e-12)   # falling in 9 of 10: no bound below the budget


class Bookkeeping(NamedTuple):
    """The part of ``learner.Bookkeeping`` that the time left reads."""

    trial: np.ndarray
    step: np.ndarray
    streak: np.ndarray
    trials_to_success: np.ndarray
    falls: np.ndarray


def test_remaining_seconds_count_the_streak_at_full_length():
    dt = 0.01

    # learner 0: 10 trials of 5 s each, one still running 1 s in; it needs at least 20 more
    # fall-free and 5 after, so every draw is the 20-trial budget: 10 more, all at 20 s.
    # Learner 1: succeeded at trial 8, 5 after.
    book = Bookkeeping(trial=np.array([10, 10]), step=np.array([100, 0]), streak=np.array([0, 2]),
                       trials_to_success=np.array([-1, 8]), falls=np.ones((2, 20), bool))
    period = np.array([5100, 6000])
    seconds = remaining_seconds_simulated(TrialParams(max_trials=20, success_streak=20, trials_after_success=5,
                                                      trial_seconds=20.0), dt, np.zeros(2), book, period,
                                          np.array([False, False]))
    assert seconds.shape == (1, 2)
    assert seconds[0, 0] == pytest.approx(10 * 20.0)
    assert seconds[0, 1] == pytest.approx(3 * 6.0)   # 13 - 10 trials left at its mean 6 s


def test_wall_seconds_left_follows_the_batch_as_it_shrinks():
    """Three of eight learners left with 10, 20 and 40 simulated seconds: three learners on 4
    rows (padded to a power of two) for the first 10 s, two on 2 rows for the next 10, then
    one on 2 rows (never one row) for the last 20; a learner on r rows costs 1 + r wall
    seconds per simulated second."""
    remaining = np.array([0, 10.0, 0, 40.0, 0, 20.0, 0, 0])
    assert wall_seconds_left(remaining, 8, lambda rows: 1.0 + rows) == 10 * 3 * 5 + 10 * 2 * 3 + 20 * 1 * 3
    assert wall_seconds_left(np.zeros(4), 4, lambda rows: 1.0) == 0.0
    # draws on a leading axis: each its own; here the second draw has one learner left, 2 rows
    draws = np.stack([remaining, np.where(remaining == 40.0, 40.0, 0.0)])
    assert wall_seconds_left(draws, 8, lambda rows: 1.0 + rows).tolist() == [270.0, 40 * 1 * 3]


def test_cost_model_takes_each_size_as_measured_and_the_nearest_for_others():
    """27 rows measured at 1.0 (the median of its last five chunks; an older, slower one
    left out) and 8 at 0.5 wall seconds per learner-second: those sizes cost that; 16 and 4
    are nearest to 8, 2 too (nearer 8 than 27)."""
    cost = cost_model({27: [9.0, 1.0, 1.0, 1.0, 1.2, 0.8], 8: [0.5]})
    assert cost(27) == 1.0 and cost(8) == 0.5
    assert cost(16) == cost(4) == cost(2) == 0.5 and cost(22) == 1.0
    assert cost_model({4: [0.2], 8: [0.6]})(6) == 0.2      # as near to both: the smaller
    assert cost_model({}) is None
    # an engine on 2 threads from 16 rows: one learner of 8 rows costs twice one of 27's
    two_from_16 = cost_model({27: [1.0]}, lambda rows: 2 if rows >= 16 else 1)
    assert two_from_16(16) == 1.0 and two_from_16(8) == two_from_16(2) == 2.0


def test_progress_line_time_left_from_a_chunks_pace():
    """Two learners, both past success, 3 and 4 trials left (succeeded at trials 2 and 3, 5
    more after), their trials so far 1 s and 2 s long (4 trials in 400 and 800 periods of
    10 ms): 3 and 8 simulated seconds left.  The first chunk, its compilation left out, ran
    1,000 robot-steps per second at 2 physics steps per period: a learner costs
    2 / (1000 x 0.01) = 0.2 wall seconds per simulated second.  Time left: 3 s of both,
    then 5 s of one, 0.2 x (3 x 2 + 5 x 1) = 2.2 s.  A batch of two compacts to no other
    size, so no compilation is still to come."""

    book = Bookkeeping(trial=np.array([4, 4]), step=np.array([0, 0]), streak=np.array([2, 1]),
                       trials_to_success=np.array([2, 3]), falls=np.zeros((2, 100), bool))
    trial = TrialParams(max_trials=100, success_streak=1, trials_after_success=5, trial_seconds=20.0)
    done, period = np.array([False, False]), np.array([400, 800])
    line = RunProgress(trial, 0.01, 2, [0.0, 0.0], done, 8, enabled=False)
    assert line.update(book, period, done, 1000.0, compile_s=30.0)["eta_s"] == pytest.approx(2.2)
    line.close()


def test_compile_seconds_left_counts_the_sizes_still_to_come():
    """27 learners, 10 left, 27 rows compiled: the ladder from 10 learners down is 27 rows
    (9-10 left: 16 rows would be more than half of 27), 8 (5-8), 4 (3-4) and 2 (1-2), three
    of them new, each at the mean of the compilations measured (4 s and 6 s): 15 s."""
    assert compile_seconds_left(10, 27, {27}, [4.0, 6.0]) == pytest.approx(15.0)
    assert compile_seconds_left(10, 27, {27, 8, 4, 2}, [4.0, 6.0]) == 0.0
    assert compile_seconds_left(10, 27, {27}, []) == 0.0  # nothing measured yet


def test_ahead_of_time_compiles_each_shape_once():
    """The chunk loop's compiler: arguments of a type met before run what was compiled for
    them (no new trace, no time added); a new shape, dtype or weak type is traced and
    compiled again, its time added."""
    traced = []

    def double(x):
        traced.append((x.shape, x.dtype, x.weak_type))
        return 2 * x

    chunk = AheadOfTime(jax.jit(double))
    assert chunk(jnp.arange(3.0)).tolist() == [0.0, 2.0, 4.0]
    first = chunk.compile_seconds
    assert first > 0
    assert chunk(jnp.ones(3)).tolist() == [2.0, 2.0, 2.0]
    assert chunk.compile_seconds == first and len(traced) == 1
    chunk(jnp.ones(4))
    chunk(jnp.ones(4, jnp.int32))
    chunk(jnp.asarray(1.0))  # weak type: a Python float's
    chunk(jnp.float32(1.0))
    assert chunk.compile_seconds > first
    assert traced == [((3,), jnp.float32, False), ((4,), jnp.float32, False), ((4,), jnp.int32, False),
                      ((), jnp.float32, True), ((), jnp.float32, False)]


def test_progress_line_adds_a_compilation_for_each_size_still_to_come():
    """Four learners past success, 4 rows compiled in the first chunk (30 s): three have 3 s
    left, one 4 s (as in the test above: 3 and 4 trials of 1 s).  All four run 3 s on 4
    rows, 0.2 x 4 x 3 = 2.4 s, then the last runs 1 s on 2 rows (compacted: at most two
    left), priced as 4 rows, the nearest size measured, 0.2 s, and compiled first: 30 s
    more.  Time left 2.4 + 0.2 + 30 = 32.6 s."""
    book = Bookkeeping(trial=np.array([4, 4, 4, 4]), step=np.zeros(4, int), streak=np.array([2, 2, 2, 1]),
                       trials_to_success=np.array([2, 2, 2, 3]), falls=np.zeros((4, 100), bool))
    trial = TrialParams(max_trials=100, success_streak=1, trials_after_success=5, trial_seconds=20.0)
    done, period = np.zeros(4, bool), np.full(4, 400)
    line = RunProgress(trial, 0.01, 2, [0.0] * 4, done, 16, enabled=False)
    assert line.update(book, period, done, 1000.0, compile_s=30.0)["eta_s"] == pytest.approx(32.6)
    line.close()


def test_the_loop_compiles_each_batch_size_before_its_first_chunk(quick_spec):
    """Four quick learners run on 4 rows until at most two are left, then on 2
    (``compacted_size``): compilation is reported with the first chunk of each size and with
    no other."""
    spec = dataclasses.replace(quick_spec, k_s=(10.0, 10.0, 0.0, 0.0), seeds=(0, 1, 2, 3))
    sim = spec.simulation("native")
    task = train.make_task(sim, spec)
    counts = []
    train.run_until_done(sim, task, spec, train.init_run(sim, task, spec), lambda state, c: counts.append(c))
    done_before = [0] + [int(np.sum(c["done"])) for c in counts[:-1]]
    rows = [train.compacted_size(spec.batch - done, spec.batch) for done in done_before]
    assert 2 in rows  # the batch did compact
    assert [c["compile_s"] > 0 for c in counts] == [r not in rows[:i] for i, r in enumerate(rows)]
