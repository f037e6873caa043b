"""Progress of a batch of learners: learners finished out of the batch, trials per second, and
the time left, estimated from the learners' own progress rather than their trial budget.

How many trials a learner still needs is unknown until it meets the success criterion; after
that its end is exact (``trials_after_success`` more).  Before it, the learner's expected
total is the mean total of the finished learners of its k_s that have run longer than it
has (else of any k_s); when none has, twice its trials so far (a learner that has not
finished in t trials is taken to need about t more); never fewer than the fall-free streak
it still needs, never more than the budget.  Its remaining trials last as long as its
trials so far did on average, except that streak, whose trials run to full length.  The
time left is all learners' remaining robot-steps at the robot-steps per second measured
over the last chunks (a rate that counts only the robots still learning), from the
session's second chunk on: the first includes compilation.
"""

from __future__ import annotations

import time

import numpy as np
from tqdm import tqdm

from mjxcpg.learning.learner import TrialParams

_RATE_CHUNKS = 5  # chunks whose median robot-steps/s sets the pace of the time left


def expected_total_trials(trial: TrialParams, k_s: np.ndarray, trials: np.ndarray, streak: np.ndarray,
                          trials_to_success: np.ndarray, done: np.ndarray) -> np.ndarray:
    """Per learner, its expected number of trials when it finishes (exact once it is done)."""
    totals = trials.astype(np.float64)
    for i in np.flatnonzero(~done):
        if trials_to_success[i] >= 0:
            totals[i] = trials_to_success[i] + trial.trials_after_success
            continue
        longer = done & (trials > trials[i])
        same_k_s = longer & (k_s == k_s[i])
        peers = trials[same_k_s if same_k_s.any() else longer]
        guess = peers.mean() if peers.size else 2.0 * trials[i]
        least = trials[i] + trial.success_streak - streak[i] + trial.trials_after_success
        totals[i] = min(max(guess, least), trial.max_trials)
    return totals


def remaining_seconds_simulated(trial: TrialParams, dt: float, k_s: np.ndarray, book, period: np.ndarray,
                                done: np.ndarray) -> np.ndarray:
    """Per learner, the simulated seconds it is expected to need still (``book``: the
    bookkeeping on the host; ``period``: control periods each learner has run)."""
    trials = np.asarray(book.trial)
    streak, trials_to_success = np.asarray(book.streak), np.asarray(book.trials_to_success)
    remaining = expected_total_trials(trial, k_s, trials, streak, trials_to_success, done) - trials
    finished_seconds = (np.asarray(period) - np.asarray(book.step)) * dt
    mean_length = np.where(trials > 0, finished_seconds / np.maximum(trials, 1), trial.trial_seconds)
    streak_left = np.where(trials_to_success >= 0, 0, np.maximum(trial.success_streak - streak, 0))
    full_length = np.minimum(streak_left, remaining)
    seconds = full_length * trial.trial_seconds + (remaining - full_length) * mean_length
    return np.where(done, 0.0, seconds)


class RunProgress:
    """The progress line of a run (tqdm on stderr; nothing when ``enabled`` is false) and
    the measures behind it, updated after every chunk."""

    def __init__(self, trial: TrialParams, dt: float, substeps: int, k_s, done: np.ndarray, trials: int,
                 enabled: bool = True):
        self.trial, self.dt, self.substeps = trial, dt, substeps
        self.k_s = np.asarray(k_s, np.float64)
        self._rates: list[float] = []
        self._last_time, self._last_trials = time.perf_counter(), trials
        self._bar = tqdm(total=len(done), initial=int(np.sum(done)), disable=not enabled, dynamic_ncols=True,
                         bar_format="{n_fmt}/{total_fmt} learners finished |{bar}| {elapsed}{postfix}")

    def update(self, book, period: np.ndarray, done: np.ndarray, robot_steps_per_s: float) -> dict:
        """After a chunk: the measures of the progress line (``eta_s`` None until known)."""
        now = time.perf_counter()
        trials = int(np.sum(book.trial))
        trials_per_s = (trials - self._last_trials) / max(now - self._last_time, 1e-9)
        self._last_time, self._last_trials = now, trials
        self._rates.append(robot_steps_per_s)
        # The session's first chunk includes compilation: no pace until a chunk without it.
        pace = float(np.median(self._rates[1:][-_RATE_CHUNKS:])) if len(self._rates) > 1 else 0.0
        seconds = remaining_seconds_simulated(self.trial, self.dt, self.k_s, book, period, done)
        eta_s = float(np.sum(seconds) / self.dt * self.substeps / pace) if pace > 0 else None
        if done.all():
            eta_s = 0.0
        measures = {"learners_finished": int(np.sum(done)), "learners_succeeded": int(np.sum(book.trials_to_success >= 0)),
                    "trials": trials, "trials_per_s": trials_per_s, "robot_steps_per_s": robot_steps_per_s,
                    "eta_s": eta_s}
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
