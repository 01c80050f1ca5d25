"""Statistics over seeds, host side (NumPy): intervals, trailing windows, level crossings.

Every report, plot and experiment of vbl takes its intervals from here, so one seed, two
arms or a curve get the same treatment everywhere:

* :func:`mean_ci95`: mean and Student-t 95 % half-width of the mean over seeds (NaN
  half-width for fewer than two seeds: one seed has no interval, and reports print the
  mean alone);
* :func:`welch_ci95`: difference of two means with Welch's 95 % half-width;
* :func:`bounded_ci95`: the mean's interval kept inside a metric's range (a rate in
  [0, 1]), or None when too few seeds give an interval wider than the range;
* :func:`seeds_to_resolve`: about how many seeds an interval needs to exclude 0;
* :func:`running_mean`: trailing moving average (shorter window at the start);
* :func:`first_crossing`: the first point where a trailing mean reaches a level;
* :func:`change_windows`: success and state counts before, right after and at the end of
  the recovery from each change of a non-stationary run.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["t_quantile_975", "mean_ci95", "welch_ci95", "bounded_ci95", "seeds_to_resolve",
           "MIN_SEEDS_BOUNDED", "running_mean", "first_crossing", "change_windows"]

MIN_SEEDS_BOUNDED = 4
"""Fewest seeds for which :func:`bounded_ci95` clips a Student t interval that crosses the
metric's range; with fewer (t quantile 4.3 at 3 seeds, 12.7 at 2) such an interval says
nothing the range does not, and reports say "too few seeds" instead."""

# 0.975 quantiles of Student's t for 1..30 degrees of freedom (standard tables).
_T975 = (12.706205, 4.302653, 3.182446, 2.776445, 2.570582, 2.446912, 2.364624, 2.306004,
         2.262157, 2.228139, 2.200985, 2.178813, 2.160369, 2.144787, 2.131450, 2.119905,
         2.109816, 2.100922, 2.093024, 2.085963, 2.079614, 2.073873, 2.068658, 2.063899,
         2.059539, 2.055529, 2.051831, 2.048407, 2.045230, 2.042272)
_Z975 = 1.959963984540054  #: 0.975 quantile of the standard normal


def t_quantile_975(df: float) -> float:
    """0.975 quantile of Student's t with ``df`` degrees of freedom (95 % two-sided).

    A table for ``df <= 30`` (a fractional ``df``, e.g. Welch's, is rounded down: the
    interval is then slightly conservative), the Cornish-Fisher expansion beyond (error
    < 1e-5); NaN for ``df < 1``."""
    if not df >= 1:
        return float("nan")
    if df < len(_T975) + 1:
        return _T975[int(df) - 1]
    z = _Z975
    g1 = (z**3 + z) / 4
    g2 = (5 * z**5 + 16 * z**3 + 3 * z) / 96
    g3 = (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / 384
    return z + g1 / df + g2 / df**2 + g3 / df**3


def mean_ci95(x: Any, axis: int = 0) -> tuple[Any, Any]:
    """(mean, 95 % half-width of the mean) of ``x`` over ``axis`` (the seeds).

    Scalars (floats) for 1-D input, arrays otherwise; the half-width is NaN where fewer
    than two values exist."""
    x = np.asarray(x, np.float64)
    n = x.shape[axis]
    m = x.mean(axis=axis)
    if n < 2:
        h = np.full_like(m, np.nan)
    else:
        h = t_quantile_975(n - 1) * x.std(axis=axis, ddof=1) / math.sqrt(n)
    return (float(m), float(h)) if np.ndim(m) == 0 else (m, h)


def welch_ci95(a: Any, b: Any) -> tuple[float, float]:
    """(mean(a) - mean(b), Welch 95 % half-width) of two samples (e.g. the seeds of two
    arms); half-width 0 when both samples are constant, NaN when either has one value."""
    a, b = np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()
    diff = float(a.mean() - b.mean())
    if a.size < 2 or b.size < 2:
        return diff, float("nan")
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    if va + vb == 0:
        return diff, 0.0
    dof = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    return diff, float(t_quantile_975(dof) * math.sqrt(va + vb))


def bounded_ci95(x: Any, lo: float, hi: float) -> tuple[float, float, float] | None:
    """(mean, lower, upper) of the mean of ``x`` (1-D, the seeds) with its Student t 95 %
    interval clipped to the metric's range ``[lo, hi]``; the interval is the mean alone
    for one seed, and None when it crosses the range with fewer than
    :data:`MIN_SEEDS_BOUNDED` seeds (too few for a useful interval)."""
    x = np.asarray(x, np.float64).ravel()
    m, h = mean_ci95(x)
    if h != h:
        return m, m, m
    if (m - h < lo or m + h > hi) and x.size < MIN_SEEDS_BOUNDED:
        return None
    return m, max(m - h, lo), min(m + h, hi)


ZERO_DIFFERENCE_RTOL = 1e-9
"""A difference within this fraction of its 95 % half-width is zero for
:func:`seeds_to_resolve` (float rounding of equal means, e.g. -1.4e-17)."""


def seeds_to_resolve(diff: float, half: float, n: int) -> int | None:
    """About how many seeds per arm a difference ``diff`` with 95 % half-width ``half``
    at ``n`` seeds needs for its interval to exclude 0, if the spread stays the same (the
    half-width falls as 1/sqrt(n)); None when ``diff`` is 0 (to
    :data:`ZERO_DIFFERENCE_RTOL` of ``half``) or ``half`` is not finite."""
    if not (math.isfinite(half) and n >= 1 and abs(diff) > ZERO_DIFFERENCE_RTOL * half):
        return None
    return max(n + 1, math.ceil(n * (1.1 * half / abs(diff)) ** 2))


def running_mean(x: Any, window: int, axis: int = -1) -> np.ndarray:
    """Trailing moving average of ``x`` along ``axis``: point i averages points
    ``max(0, i - window + 1) .. i`` (the first ``window - 1`` points average fewer)."""
    if int(window) < 1:
        raise ValueError(f"window={window}: must be >= 1")
    x = np.moveaxis(np.asarray(x, np.float64), axis, -1)
    c = np.cumsum(np.pad(x, [(0, 0)] * (x.ndim - 1) + [(1, 0)]), axis=-1)
    n = np.arange(1, x.shape[-1] + 1)
    lo = np.maximum(n - int(window), 0)
    return np.moveaxis((c[..., n] - c[..., lo]) / (n - lo), -1, axis)


def first_crossing(values: Any, clock: Any, level: float, window: int = 1) -> np.ndarray:
    """Per column: ``clock`` at the first row where the trailing mean of ``values`` over
    ``window`` rows (:func:`running_mean`) is >= ``level``; NaN if never.

    ``values``, ``clock``: (rows, columns), e.g. success per chunk and cumulative trials
    per chunk, one column per seed -> (columns,) float."""
    values, clock = np.asarray(values, np.float64), np.asarray(clock, np.float64)
    if values.shape != clock.shape or values.ndim != 2:
        raise ValueError(f"values {values.shape} and clock {clock.shape} must both be "
                         "(rows, columns)")
    hit = running_mean(values, window, axis=0) >= level
    first = np.argmax(hit, axis=0)
    return np.where(hit.any(axis=0), clock[first, np.arange(clock.shape[1])], np.nan)


def change_windows(success: Any, states: Any, changes: tuple[int, ...],
                   window: int) -> list[dict[str, Any]]:
    """Around each change of a non-stationary run (trial indices ``changes``).

    ``success``, ``states``: (seeds, trials). Per change c (ending at the next change or
    at the last trial): ``rates`` (seeds, 3), the success rate in the ``window`` trials
    before c, right after c and at the end of its recovery (the ``window`` trials before
    its end; NaN for an empty span); ``states`` (seeds, 3) just before c, ``window`` trials
    after it and at its end; ``spans``, ``change``, ``end``."""
    success, states = np.asarray(success, np.float64), np.asarray(states)
    n = success.shape[1]
    out = []
    for i, c in enumerate(changes):
        end = changes[i + 1] if i + 1 < len(changes) else n
        spans = [(c - window, c), (c, c + window), (end - window, end)]
        rates = [success[:, max(a, 0):min(b, n)].mean(axis=1) if min(b, n) > max(a, 0)
                 else np.full(success.shape[0], np.nan) for a, b in spans]
        st = [states[:, min(max(t, 0), n - 1)] for t in (c - 1, c + window, end - 1)]
        out.append(dict(change=c, end=end, spans=spans, rates=np.stack(rates, 1),
                        states=np.stack(st, 1)))
    return out
