"""Input checks of the non-jitted entry point :func:`vbl.sysid.identify`."""

from __future__ import annotations

import numpy as np

from vbl.sysid.params import CVAParams

__all__ = ["check_data", "min_length"]


def min_length(lag: int, horizon: int, m: int, q: int, factor: float) -> int:
    """Smallest N with N - k - l + 1 >= factor * (l + k)(m + q)."""
    return int(np.ceil(factor * (lag + horizon) * (m + q))) + lag + horizon - 1


def check_data(u, y, params: CVAParams) -> tuple[np.ndarray, np.ndarray, bool]:
    """Validate and return ``u (B, N, m)``, ``y (B, N, q)`` as float64 arrays and ``batched``.

    Accepts one data set ``(N, m)``, ``(N, q)`` or a batch ``(B, N, m)``, ``(B, N, q)``.
    Raises ValueError for wrong shapes, NaN/inf, constant channels and data too short for
    the largest lag tried.
    """
    u = np.asarray(u)
    y = np.asarray(y)
    for name, a in (("u", u), ("y", y)):
        if a.dtype.kind not in "iuf":
            raise ValueError(f"{name} must be a real numeric array, got dtype {a.dtype}")
    if u.ndim != y.ndim or u.ndim not in (2, 3):
        raise ValueError(f"u and y must both be (N, m) and (N, q) or (B, N, m) and (B, N, q); "
                         f"got shapes {u.shape} and {y.shape}")
    batched = u.ndim == 3
    if not batched:
        u, y = u[None], y[None]
    if u.shape[:2] != y.shape[:2]:
        raise ValueError(f"u {u.shape} and y {y.shape} must share the data-set and time axes")
    b, n, m = u.shape
    q = y.shape[2]
    if b == 0 or m == 0 or q == 0:
        raise ValueError(f"need at least one data set, input and output; got B={b}, m={m}, "
                         f"q={q}")
    u = u.astype(np.float64)
    y = y.astype(np.float64)
    for name, a in (("u", u), ("y", y)):
        bad = ~np.isfinite(a)
        if bad.any():
            ds, t, ch = np.argwhere(bad)[0]
            raise ValueError(f"{name} contains NaN or inf ({int(bad.sum())} values; first in "
                             f"data set {ds}, time {t}, channel {ch}); identification needs "
                             "finite data")
    lag = max(params.lags())
    horizon = params.horizon_for(lag)
    need = min_length(lag, horizon, m, q, params.min_samples_factor)
    if n < need:
        raise ValueError(
            f"data too short: N={n} samples, but lag l={lag} and horizon k={horizon} with "
            f"m={m}, q={q} need N >= {need} (N-k-l+1 >= {params.min_samples_factor} x "
            f"(l+k)(m+q)); give longer records or lower lag/lag_max/horizon")
    for name, a in (("u", u), ("y", y)):
        std = a.std(axis=1)
        const = std <= params.const_tol * np.abs(a).max(axis=1)
        if const.any():
            ds, ch = np.argwhere(const)[0]
            raise ValueError(f"{name} channel {ch} of data set {ds} is constant "
                             f"({int(const.sum())} constant channel(s) in all); CVA needs "
                             "every channel to vary: drop it or add excitation")
    return u, y, batched
