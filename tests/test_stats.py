"""Intervals and trends of mjxcpg.training.stats against closed forms."""

import numpy as np

from mjxcpg.training import stats


def test_spearman_of_monotone_and_reversed_orders():
    x = [0, 1, 2, 3, 4, 5, 10]
    assert stats.spearman(x, np.exp(x)) == 1.0
    assert stats.spearman(x, [-v for v in x]) == -1.0


def test_spearman_matches_the_rank_difference_formula():
    """Without ties rho = 1 - 6 sum d^2 / (n (n^2 - 1))."""
    x = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 10.0]
    y = [0.02, 0.05, 0.04, 0.07, 0.06, 0.08, 0.09]   # ranks 1 3 2 5 4 6 7
    d = np.array([1, 2, 3, 4, 5, 6, 7]) - np.array([1, 3, 2, 5, 4, 6, 7])
    n = 7
    np.testing.assert_allclose(stats.spearman(x, y), 1 - 6 * (d**2).sum() / (n * (n**2 - 1)))


def test_ties_get_their_mean_rank():
    np.testing.assert_array_equal(stats.ranks([3.0, 1.0, 3.0, 2.0]), [3.5, 1.0, 3.5, 2.0])


def test_slope_of_an_exact_line_has_no_spread():
    k = np.repeat([0.0, 1.0, 2.0, 5.0, 10.0], 4)
    estimate = stats.slope_interval(k, 0.03 + 0.004 * k)
    np.testing.assert_allclose([estimate.value, estimate.low, estimate.high], 0.004, rtol=1e-9)


def test_mean_interval_covers_like_the_normal_one():
    """For 400 normal samples the 95% bootstrap interval of the mean is close to
    mean +- 1.96 s / sqrt(n): within 10% in width (bootstrap and sample noise)."""
    x = np.random.default_rng(3).normal(1.0, 2.0, 400)
    estimate = stats.mean_interval(x)
    normal_half_width = 1.96 * x.std(ddof=1) / np.sqrt(x.size)
    assert estimate.value == x.mean()
    np.testing.assert_allclose((estimate.high - estimate.low) / 2, normal_half_width, rtol=0.1)
    assert estimate.low < x.mean() < estimate.high


def test_empty_and_single_values():
    assert np.isnan(stats.mean_interval([]).value) and stats.mean_interval([]).format() == "-"
    assert stats.mean_interval([0.5]).format(".2f") == "0.50"
