"""vbl.stats against SciPy (a peer library) and against hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from vbl.stats import (
    bounded_ci95,
    change_windows,
    first_crossing,
    mean_ci95,
    running_mean,
    seeds_to_resolve,
    t_quantile_975,
    welch_ci95,
)


@pytest.mark.parametrize("df", [1, 2, 3, 7, 15, 30, 31, 45, 100, 1000])
def test_t_quantile_matches_scipy(df):
    assert t_quantile_975(df) == pytest.approx(sps.t.ppf(0.975, df), rel=1e-5)


@pytest.mark.parametrize("df", [1.5, 2.7, 12.2, 29.9])
def test_fractional_df_is_conservative(df):
    true = sps.t.ppf(0.975, df)
    assert true <= t_quantile_975(df) <= sps.t.ppf(0.975, np.floor(df)) + 1e-6


def test_mean_ci95_is_scipys_t_interval():
    x = np.random.default_rng(0).normal(0.4, 0.2, size=(9, 3))
    m, h = mean_ci95(x)
    lo, hi = sps.t.interval(0.95, 8, loc=x.mean(0), scale=sps.sem(x, axis=0))
    np.testing.assert_allclose(m, x.mean(0))
    np.testing.assert_allclose(h, (hi - lo) / 2, rtol=1e-6)
    m1, h1 = mean_ci95(x[:, 0])
    assert isinstance(m1, float) and h1 == pytest.approx(h[0])


def test_mean_ci95_over_another_axis_counts_that_axis_as_the_seeds():
    x = np.random.default_rng(3).normal(0.4, 0.2, size=(4, 9))  # 4 metrics x 9 seeds
    m, h = mean_ci95(x, axis=1)
    lo, hi = sps.t.interval(0.95, 8, loc=x.mean(1), scale=sps.sem(x, axis=1))
    np.testing.assert_allclose(m, x.mean(1))
    np.testing.assert_allclose(h, (hi - lo) / 2, rtol=1e-6)


def test_one_seed_has_no_interval():
    m, h = mean_ci95([0.7])
    assert m == 0.7 and np.isnan(h)
    assert np.isnan(welch_ci95([1.0], [0.0, 1.0])[1])


def test_welch_matches_scipy():
    rng = np.random.default_rng(1)
    a, b = rng.normal(1.0, 1.0, 6), rng.normal(0.0, 3.0, 11)
    d, h = welch_ci95(a, b)
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    dof = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    assert d == pytest.approx(a.mean() - b.mean())
    exact = sps.t.ppf(0.975, dof) * np.sqrt(va + vb)
    assert exact <= h <= exact * 1.1  # df rounded down: conservative, barely
    assert welch_ci95([2.0, 2.0], [1.0, 1.0, 1.0]) == (1.0, 0.0)


def test_running_mean_against_a_loop():
    x = np.random.default_rng(2).random((3, 17))
    r = running_mean(x, 5)
    for i in range(17):
        np.testing.assert_allclose(r[:, i], x[:, max(0, i - 4):i + 1].mean(1))
    np.testing.assert_allclose(running_mean(x.T, 5, axis=0), r.T)
    with pytest.raises(ValueError, match="window"):
        running_mean(x, 0)


def test_first_crossing_by_hand():
    success = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.2], [0.0, 0.2]])
    trials = np.cumsum(np.full_like(success, 10.0), axis=0)
    np.testing.assert_array_equal(first_crossing(success, trials, 0.5), [20.0, np.nan])
    # window 2: (0 + 1) / 2 = 0.5 reaches the level at the second row already
    np.testing.assert_array_equal(first_crossing(success, trials, 0.5, window=2), [20.0, np.nan])
    np.testing.assert_array_equal(first_crossing(success, trials, 0.75, window=2), [30.0, np.nan])
    # a clock that is not one per value (even one that would broadcast) is refused
    for clock in (trials[:, :1], trials[:3], trials.ravel()):
        with pytest.raises(ValueError, match="must both be"):
            first_crossing(success, clock, 0.5)


def test_change_windows_by_hand():
    success = np.array([[1, 1, 0, 0, 1, 1, 1, 1]], float)
    states = np.arange(8)[None] * 10
    (w,) = change_windows(success, states, (2,), window=2)
    np.testing.assert_array_equal(w["rates"], [[1.0, 0.0, 1.0]])
    np.testing.assert_array_equal(w["states"], [[10, 40, 70]])
    assert w["spans"] == [(0, 2), (2, 4), (6, 8)] and w["end"] == 8


@pytest.mark.parametrize("diff, half, n", [(1.0, 2.0, 4), (-0.3, 0.5, 8), (2.0, 2.05, 16),
                                           (0.01, 3.0, 64)])
def test_seeds_to_resolve_is_the_first_count_whose_projected_interval_clears_zero(diff,
                                                                                  half, n):
    # the half-width falls as 1/sqrt(seeds); 10 % margin on |diff|
    m = seeds_to_resolve(diff, half, n)
    assert m > n and half * np.sqrt(n / m) <= abs(diff) / 1.1
    assert m == n + 1 or half * np.sqrt(n / (m - 1)) > abs(diff) / 1.1


@pytest.mark.parametrize("diff, half", [(0.0, 0.2), (-1.39e-17, 0.234), (0.5, float("nan"))])
def test_no_seed_count_for_a_zero_difference_or_no_interval(diff, half):
    # -1.39e-17: the float mean of per-seed differences that are exactly opposite
    assert seeds_to_resolve(diff, half, 4) is None


def test_welch_with_one_value_in_either_arm_has_no_interval():
    for a, b in (([0.5], [0.1, 0.2, 0.3]), ([0.1, 0.2, 0.3], [0.5])):
        d, h = welch_ci95(a, b)
        assert d == pytest.approx(np.mean(a) - np.mean(b)) and np.isnan(h)


def test_bounded_ci95_of_one_seed_is_the_value_itself():
    assert bounded_ci95([0.25], 0.0, 1.0) == (0.25, 0.25, 0.25)
    assert bounded_ci95([1.0], 0.0, 1.0) == (1.0, 1.0, 1.0)


def test_no_seed_count_for_an_infinite_interval():
    assert seeds_to_resolve(0.5, float("inf"), 4) is None


def test_change_windows_of_two_changes_by_hand():
    """The first change's recovery ends at the second; a change sooner than ``window``
    after the start averages the trials it has."""
    success = np.array([[1, 0, 1, 1, 0, 0, 1, 0, 1, 1]], float)
    states = np.arange(10)[None] + 100
    first, second = change_windows(success, states, (1, 6), window=3)
    assert (first["change"], first["end"], second["end"]) == (1, 6, 10)
    assert first["spans"] == [(-2, 1), (1, 4), (3, 6)]
    np.testing.assert_allclose(first["rates"], [[1.0, 2 / 3, 1 / 3]])
    np.testing.assert_array_equal(first["states"], [[100, 104, 105]])
    np.testing.assert_allclose(second["rates"], [[1 / 3, 2 / 3, 2 / 3]])
    np.testing.assert_array_equal(second["states"], [[105, 109, 109]])
