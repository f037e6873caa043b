"""Intervals and trends over learners: bootstrap confidence intervals, Spearman's rho, and
the least-squares slope of a response against k_s.

Every interval is a 95% percentile bootstrap over learners (resampled with replacement,
``RESAMPLES`` times, from a fixed seed, so a report is the same each time it is written).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

RESAMPLES = 10_000
LEVEL = 0.95


class Estimate(NamedTuple):
    value: float
    low: float    # the 95% interval
    high: float
    n: int

    def as_dict(self) -> dict:
        return self._asdict()

    def format(self, spec: str = ".3f") -> str:
        if not np.isfinite(self.value):
            return "-"
        if self.n < 2:
            return format(self.value, spec)
        return f"{self.value:{spec}} [{self.low:{spec}}, {self.high:{spec}}]"


def _percentiles(samples: np.ndarray) -> tuple[float, float]:
    tail = 100 * (1 - LEVEL) / 2
    return float(np.percentile(samples, tail)), float(np.percentile(samples, 100 - tail))


def mean_interval(values, seed: int = 0) -> Estimate:
    """The mean of ``values`` with its 95% bootstrap interval (NaN for no values)."""
    x = np.asarray(values, float)
    if x.size == 0:
        return Estimate(float("nan"), float("nan"), float("nan"), 0)
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, (RESAMPLES, x.size))].mean(axis=1)
    return Estimate(float(x.mean()), *_percentiles(means), int(x.size))


def ranks(x: np.ndarray) -> np.ndarray:
    """Ranks from 1, ties given their mean rank."""
    x = np.asarray(x, float)
    order = np.argsort(x, kind="stable")
    ranked = np.empty(x.size)
    ranked[order] = np.arange(1, x.size + 1)
    for value in np.unique(x):
        tied = x == value
        ranked[tied] = ranked[tied].mean()
    return ranked


def spearman(x, y) -> float:
    """Spearman's rank correlation: Pearson's correlation of the ranks."""
    rx, ry = ranks(np.asarray(x)), ranks(np.asarray(y))
    if rx.std() == 0 or ry.std() == 0:
        return float("nan")
    return float(np.corrcoef(rx, ry)[0, 1])


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    dx = x - x.mean()
    denominator = float(dx @ dx)
    return float(dx @ (y - y.mean()) / denominator) if denominator > 0 else float("nan")


def slope_interval(x, y, seed: int = 0) -> Estimate:
    """Least-squares slope of ``y`` on ``x`` with its 95% bootstrap interval (pairs resampled)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, x.size, (RESAMPLES, x.size))
    slopes = np.array([_slope(x[p], y[p]) for p in picks])
    slopes = slopes[np.isfinite(slopes)]
    return Estimate(_slope(x, y), *_percentiles(slopes), int(x.size))
