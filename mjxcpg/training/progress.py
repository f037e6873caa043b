"""Progress of a batch of learners: learners finished out of the batch, trials per second, and
the time left, estimated from the learners' own progress rather than their trial budget.

How many trials a learner still needs is unknown until it meets the success criterion; after
that its end is exact (``trials_after_success`` more).  Before it, the learner's total is
drawn from the totals of the finished learners of its k_s that have run longer than it has
(else of any k_s).  When none has, the trials to success are taken as scale-free (Lindy's
law, a Pareto tail of index 1: a learner that has not succeeded in t trials is as likely to
need more than 2t as fewer), within the budget; then the trials after success.  The times to
success of this project's learners are heavy-tailed in just this way (a few k_s = 0 learners
take ten times the others).  A learner's own falls bound each draw: the streak it needs
takes ``trials_to_streak`` trials on average at the fall rate its history gives
(``history_fall_rate``: streaks completed at the rates of its windows of ``WINDOW_TRIALS``
trials; an overestimate for a learner that is still learning not to fall).  Never fewer
than the fall-free streak it still needs, never more than the budget.  Its remaining trials
last as long as its trials so far did on average, except that streak, whose trials run to
full length.

The time left follows the batch as it shrinks: learners finish in the order of their
remaining simulated time, and each stretch runs the rows ``train.compacted_size`` gives
the learners left.  Each learner left costs, in wall seconds per simulated second, what one
did in the chunks of that many rows (``cost_model``), or in those of the nearest size run,
scaled by the threads the engine steps either size on.  This is the C engines' cost:
physics, one robot per unfinished learner, outweighs the rest, and a finished learner's
robot is not stepped.  MJX steps every row, so there it holds within one size only.  Pace
leaves compilation out (the loop compiles each size ahead of its first chunk), so the first
chunk already sets it; each size still to come adds what a compilation took on average.  (With
several processes, process 0's line counts its own block, which it steps and compacts on
its own.)

The batch ends with its slowest learner, so the time left is the mean over ``ETA_DRAWS``
draws of every learner's total, not the time left at each learner's mean total: with many
learners in a heavy tail, the slowest of them needs far more than any one does on average.
The draws come from one seed after every chunk, a column of uniform numbers per learner,
so the estimate moves only with the learners.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from tqdm import tqdm

from mjxcpg.learning.learner import TrialParams
from mjxcpg.training import train

_RATE_CHUNKS = 5  # chunks whose median wall time per simulated second sets a size's pace
WINDOW_TRIALS = 50  # the trials of a window whose falls give one fall rate of a learner
ETA_DRAWS = 256     # draws of the learners' totals; the time left is their mean (module docstring)


def sampled_total_trials(trial: TrialParams, k_s: np.ndarray, trials: np.ndarray, streak: np.ndarray,
                         trials_to_success: np.ndarray, done: np.ndarray, draws: int,
                         rng: np.random.Generator, fall_rate: np.ndarray | None = None) -> np.ndarray:
    """(draws, learners): draws of each learner's number of trials when it finishes (exact
    once it has succeeded or is done); ``fall_rate``, each learner's fall rate
    (``history_fall_rate``), bounds the draws (module docstring).  Each learner has its own
    column of uniform numbers from ``rng``, so its draws do not move when another learner
    succeeds or finishes."""
    totals = np.tile(trials.astype(np.float64), (draws, 1))
    uniform = rng.random((draws, len(trials)))
    for i in np.flatnonzero(~done):
        if trials_to_success[i] >= 0:
            totals[:, i] = trials_to_success[i] + trial.trials_after_success
            continue
        longer = done & (trials > trials[i])
        same_k_s = longer & (k_s == k_s[i])
        peers = trials[same_k_s if same_k_s.any() else longer]
        if peers.size:
            guess = np.sort(peers)[(uniform[:, i] * peers.size).astype(int)].astype(np.float64)
        else:
            guess = pareto_draws(trials[i], trial.max_trials, uniform[:, i]) + trial.trials_after_success
        if fall_rate is not None:
            guess = np.minimum(guess, trials[i] + trials_to_streak(fall_rate[i], streak[i], trial.success_streak)
                               + trial.trials_after_success)
        least = trials[i] + trial.success_streak - streak[i] + trial.trials_after_success
        totals[:, i] = np.clip(guess, least, trial.max_trials)
    return totals


def pareto_draws(trials: float, budget: float, uniform: np.ndarray) -> np.ndarray:
    """Draws of min(T, budget) for T with P(T > x) = trials / x beyond ``trials`` (Lindy's
    law: T = trials / (1 - u) for each u of ``uniform``, uniform on [0, 1)); their mean is
    ``lindy_mean``."""
    return np.minimum(trials / (1.0 - uniform), budget)


def lindy_mean(trials: float, budget: float) -> float:
    """The mean of min(T, budget) for T with P(T > x) = trials / x beyond ``trials`` (a Pareto
    tail of index 1): trials (1 + ln(budget / trials)); 0 before the first trial (the closed
    form against which ``pareto_draws`` is checked)."""
    return trials * (1.0 + np.log(budget / trials)) if 0 < trials < budget else float(min(trials, budget))


def trials_to_streak(fall_rate: float, streak: int, needed: int) -> float:
    """The expected trials until ``needed`` successive trials without a fall, from a streak of
    ``streak``, when each trial falls with probability p = ``fall_rate`` independently:
    (q^-needed - q^-streak) / p with q = 1 - p (the waiting time for a run of successes)."""
    if streak >= needed:
        return 0.0
    if fall_rate <= 0:
        return float(needed - streak)
    if fall_rate >= 1:
        return float("inf")
    q = 1.0 - fall_rate
    return (q ** -needed - q ** -streak) / fall_rate


def recent_fall_rate(falls: np.ndarray, trials: np.ndarray, window: int = WINDOW_TRIALS) -> np.ndarray:
    """Per learner, ``laplace_rate`` over its last min(trials, ``window``) trials (never
    exactly 0 or 1); ``falls``: (learners, budget) per trial."""
    return np.array([laplace_rate(falls[i, max(0, n - window):n]) for i, n in enumerate(trials)])


def laplace_rate(falls: np.ndarray) -> float:
    """(falls + 1) / (n + 2) over n trials' ``falls`` (Laplace's rule of succession)."""
    return (float(np.sum(falls)) + 1.0) / (np.size(falls) + 2.0)


def history_fall_rate(falls: np.ndarray, trials: np.ndarray, needed: int, window: int = WINDOW_TRIALS) -> np.ndarray:
    """Per learner, the fall rate whose streak of ``needed`` takes as long on average
    (``trials_to_streak``) as it would if the learner's coming trials fell as its past ones
    did: its trials so far cut into windows of ``window`` back from the newest, each window's
    rate by Laplace's rule, and streaks completed at each window's rate, 1 / trials_to_streak
    per trial, for the window's share of the trials.  Equal to every window's rate when they
    are all equal.  The waiting time is so steep a function of the rate (0.14 and 0.26 wait
    139 and 1,580 trials for 20) that one window's count, its standard deviation 0.06 at 0.2
    over 50 trials, says little; a learner whose rate wanders is most likely to finish in its
    better stretches, which the mean of the completion rates counts and a mean rate does not.
    ``falls``: (learners, budget) per trial; 1.0 before any trial."""
    rates = np.ones(len(trials))
    for i, n in enumerate(trials):
        if n <= 0:
            continue
        edges = np.arange(n, 0, -window)[::-1]
        completions = 0.0
        for end in edges:
            segment = falls[i, max(0, end - window):end]
            completions += segment.size / trials_to_streak(laplace_rate(segment), 0, needed)
        rates[i] = _rate_for_wait(n / completions, needed)
    return rates


def _rate_for_wait(wait: float, needed: int) -> float:
    """The fall rate p with trials_to_streak(p, 0, ``needed``) = ``wait`` (bisection: the
    wait grows with p, from ``needed`` at p = 0)."""
    if wait <= needed:
        return 0.0
    low, high = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if trials_to_streak(mid, 0, needed) < wait else (low, mid)
    return 0.5 * (low + high)


def wall_seconds_left(remaining: np.ndarray, batch: int, cost: Callable[[int], float]) -> np.ndarray:
    """Wall seconds until every learner has simulated its ``remaining`` seconds (0 for the
    finished; last axis: learners, any leading axes: draws), with the rows a chunk runs
    shrinking as learners finish (``train.compacted_size``), and each learner left costing
    ``cost(rows)`` wall seconds per simulated second in a batch of that many rows."""
    levels = np.sort(remaining, axis=-1)  # the finished first, at 0: their stretches are empty
    stretches = np.diff(levels, axis=-1, prepend=0.0)
    learners = levels.shape[-1]
    costs = np.array([n * cost(train.compacted_size(n, batch)) for n in range(learners, 0, -1)])
    return stretches @ costs


def remaining_seconds_simulated(trial: TrialParams, dt: float, k_s: np.ndarray, book, period: np.ndarray,
                                done: np.ndarray, draws: int = 1, seed: int = 0) -> np.ndarray:
    """(draws, learners): the simulated seconds each learner may still need, over ``draws``
    draws of its total trials (``sampled_total_trials`` from a generator seeded ``seed``;
    ``book``: the bookkeeping on the host; ``period``: control periods each learner has run)."""
    trials = np.asarray(book.trial)
    streak, trials_to_success = np.asarray(book.streak), np.asarray(book.trials_to_success)
    fall_rate = history_fall_rate(np.asarray(book.falls), trials, trial.success_streak)
    remaining = sampled_total_trials(trial, k_s, trials, streak, trials_to_success, done, draws,
                                     np.random.default_rng(seed), fall_rate) - trials
    finished_seconds = (np.asarray(period) - np.asarray(book.step)) * dt
    mean_length = np.where(trials > 0, finished_seconds / np.maximum(trials, 1), trial.trial_seconds)
    streak_left = np.where(trials_to_success >= 0, 0, np.maximum(trial.success_streak - streak, 0))
    full_length = np.minimum(streak_left, remaining)
    seconds = full_length * trial.trial_seconds + (remaining - full_length) * mean_length
    return np.where(done, 0.0, seconds)


def compile_seconds_left(active: int, batch: int, compiled: set[int], compile_seconds: list[float]) -> float:
    """The most compilation still to come while ``active`` learners of ``batch`` finish: one
    for each size of ``train.compacted_size``'s ladder not in ``compiled``, at the mean of
    the ``compile_seconds`` measured (0 before any).  A size is skipped when enough learners
    finish in one chunk, so this is an upper bound."""
    sizes = {train.compacted_size(n, batch) for n in range(1, active + 1)} - compiled
    return len(sizes) * float(np.mean(compile_seconds)) if compile_seconds else 0.0


def cost_model(costs: dict[int, list[float]],
               threads_for: Callable[[int], int] = lambda rows: 1) -> Callable[[int], float] | None:
    """Wall seconds per simulated second of one unfinished learner in a batch of ``rows``,
    from ``costs``: per size measured, that cost in each of its chunks (the median of the
    last few sets it).  A size not yet run costs what the nearest size measured did (the
    smaller of two as near), times the threads that stepped that size over those that will
    step this one (``threads_for(rows)``, the engine's ``threads_for``).  None before any
    measurement."""
    medians = {rows: float(np.median(c[-_RATE_CHUNKS:])) for rows, c in costs.items() if c}
    if not medians:
        return None

    def cost(rows: int) -> float:
        nearest = min(medians, key=lambda r: (abs(r - rows), r))
        return medians[nearest] * threads_for(nearest) / threads_for(rows)

    return cost


class RunProgress:
    """The progress line of a run (tqdm on stderr; nothing when ``enabled`` is false) and
    the measures behind it, updated after every chunk; ``threads_for``: the engine's."""

    def __init__(self, trial: TrialParams, dt: float, substeps: int, k_s, done: np.ndarray, trials: int,
                 enabled: bool = True, threads_for: Callable[[int], int] = lambda rows: 1):
        self.trial, self.dt, self.substeps, self._threads_for = trial, dt, substeps, threads_for
        self.k_s = np.asarray(k_s, np.float64)
        # rows -> per chunk, wall seconds per simulated second of each unfinished learner
        self._costs: dict[int, list[float]] = {}
        self._compile_seconds: list[float] = []  # each chunk's that compiled
        self._compiled_sizes: set[int] = set()
        self._done = np.asarray(done)
        self._last_time, self._last_trials = time.perf_counter(), trials
        self._bar = tqdm(total=len(done), initial=int(np.sum(done)), disable=not enabled, dynamic_ncols=True,
                         bar_format="{n_fmt}/{total_fmt} learners finished |{bar}| {elapsed}{postfix}")

    def update(self, book, period: np.ndarray, done: np.ndarray, robot_steps_per_s: float,
               compile_s: float = 0.0) -> dict:
        """After a chunk: the measures of the progress line (``eta_s`` None until known);
        ``robot_steps_per_s``: the chunk's pace, its compilation (``compile_s``) left out."""
        now = time.perf_counter()
        trials = int(np.sum(book.trial))
        trials_per_s = (trials - self._last_trials) / max(now - self._last_time, 1e-9)
        self._last_time, self._last_trials = now, trials
        active = int(np.sum(~self._done))
        rows = train.compacted_size(active, len(done))
        if robot_steps_per_s > 0:
            self._costs.setdefault(rows, []).append(self.substeps / (robot_steps_per_s * self.dt))
        if compile_s > 0:
            self._compile_seconds.append(compile_s)
            self._compiled_sizes.add(rows)
        self._done = np.asarray(done)
        seconds = remaining_seconds_simulated(self.trial, self.dt, self.k_s, book, period, done, ETA_DRAWS)
        cost = cost_model(self._costs, self._threads_for)
        eta_s = None if cost is None else float(
            np.mean(wall_seconds_left(seconds, len(done), cost))
            + compile_seconds_left(int(np.sum(~self._done)), len(done), self._compiled_sizes, self._compile_seconds))
        if done.all():
            eta_s = 0.0
        measures = {"learners_finished": int(np.sum(done)), "learners_succeeded": int(np.sum(book.trials_to_success >= 0)),
                    "trials": trials, "trials_per_s": trials_per_s, "robot_steps_per_s": robot_steps_per_s,
                    "compile_s": compile_s, "eta_s": eta_s}
        self._bar.n = measures["learners_finished"]
        self._bar.set_postfix_str(
            f"{trials} trials, {trials_per_s:.1f} trials/s, succeeded {measures['learners_succeeded']}, "
            f"ETA {'?' if eta_s is None else _clock(eta_s)}")
        return measures

    def close(self) -> None:
        self._bar.close()


def _clock(seconds: float) -> str:
    minutes, s = divmod(round(seconds), 60)
    hours, m = divmod(minutes, 60)
    return f"{hours}:{m:02d}:{s:02d}" if hours else f"{m:02d}:{s:02d}"
