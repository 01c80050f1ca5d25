"""Input checks of the non-jitted entry point :func:`vbl.sysid.identify`."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from vbl.sysid.params import CVAParams

__all__ = ["check_data", "checked", "min_length", "prepare_scale", "warn_collinear",
           "safe_range", "CollinearWarning", "channel_major", "channel_stats", "ChannelStats"]


class CollinearWarning(UserWarning):
    """Duplicated or collinear channels of u or y (identification regularises them)."""


def channel_major(x: np.ndarray) -> np.ndarray:
    """``x (B, N, c)`` as a contiguous ``(B, c, N)`` copy: NumPy reduces over a contiguous
    last axis much faster than over the time axis of ``(B, N, c)`` with few channels."""
    return np.ascontiguousarray(np.swapaxes(x, 1, 2))


def _abs_max(xt: np.ndarray) -> np.ndarray:
    """max |x| per data set and channel ``(B, c)`` of channel-major ``xt (B, c, N)``."""
    return np.maximum(xt.max(axis=-1), -xt.min(axis=-1))


def min_length(lag: int, horizon: int, m: int, q: int, factor: float) -> int:
    """Smallest N with N - k - l + 1 >= factor * (l + k)(m + q)."""
    return int(np.ceil(factor * (lag + horizon) * (m + q))) + lag + horizon - 1


def check_data(u, y, params: CVAParams) -> tuple[np.ndarray, np.ndarray, bool]:
    """Validate and return ``u (B, N, m)``, ``y (B, N, q)`` as float64 arrays and ``batched``.

    Accepts one data set ``(N, m)``, ``(N, q)`` or a batch ``(B, N, m)``, ``(B, N, q)``.
    Raises ValueError for wrong shapes, NaN/inf, constant channels and data too short for
    the largest lag tried.
    """
    return checked(u, y, params)[:3]


@dataclass(frozen=True)
class ChannelStats:
    """Per data set and channel of one signal ``(B, N, c)``: what the checks, the collinearity
    warning and :func:`prepare_scale` read."""

    abs_max: np.ndarray   # (B, c) max |x|
    std: np.ndarray       # (B, c) standard deviation (over N)
    corr: np.ndarray      # (B, c, c) correlation matrix of the channels


def channel_stats(x: np.ndarray) -> ChannelStats:
    """:class:`ChannelStats` of finite ``x (B, N, c)`` from one channel-major copy: scaled by
    each channel's max |x| (no overflow or underflow in the squares), centred in place, and
    one product of the centred channels for the variances and correlations."""
    xt = channel_major(x)
    amax = _abs_max(xt)
    xt /= np.maximum(amax, np.finfo(xt.dtype).tiny)[..., None]
    xt -= xt.mean(axis=-1, keepdims=True)
    g = np.matmul(xt, np.swapaxes(xt, 1, 2))                       # (B, c, c)
    sq = np.diagonal(g, axis1=1, axis2=2)                          # (B, c) sums of squares
    norm = np.sqrt(np.maximum(sq, np.finfo(xt.dtype).tiny))
    return ChannelStats(abs_max=amax, std=np.sqrt(sq / xt.shape[-1]) * amax,
                        corr=g / (norm[..., :, None] * norm[..., None, :]))


def checked(u, y, params: CVAParams):
    """:func:`check_data`, also returning the :class:`ChannelStats` of u and y:
    ``(u, y, batched, stats_u, stats_y)``."""
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
    u = np.asarray(u, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    for name, a in (("u", u), ("y", y)):
        if np.isfinite(a.sum()):        # one pass; an inf sum of finite values checks below
            continue
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
    stats = channel_stats(u), channel_stats(y)
    for name, st in zip(("u", "y"), stats, strict=True):
        const = st.std <= params.const_tol * st.abs_max
        if const.any():
            ds, ch = np.argwhere(const)[0]
            raise ValueError(f"{name} channel {ch} of data set {ds} is constant "
                             f"({int(const.sum())} constant channel(s) in all); CVA needs "
                             "every channel to vary: drop it or add excitation")
    return u, y, batched, *stats


def safe_range(dtype: str) -> tuple[float, float]:
    """Magnitudes ``(lo, hi)`` = 2^-(e/4), 2^(e/4) (e = the dtype's largest binary exponent)
    within which sums of squares over any record neither overflow nor lose all precision."""
    e = np.finfo(np.float32 if dtype == "float32" else np.float64).maxexp
    return 2.0 ** -(e // 4), 2.0 ** (e // 4)


def prepare_scale(u: np.ndarray, y: np.ndarray, params: CVAParams,
                  abs_max: tuple[np.ndarray, np.ndarray]):
    """Bring data near float limits into range without changing the identification.

    Per data set and channel: with ``dtype='float32'`` and ``demean`` the mean is removed in
    float64 first (a mean of 1e7 would leave float32 no digits for the variation); with
    ``standardize`` a channel whose magnitude is outside :func:`safe_range` is divided by a
    power of two (exact, so the standardised data are the same bits). Returns ``u, y`` and
    ``(u_off, u_mul, y_off, y_mul)`` (B, m) / (B, q) with raw = off + mul * prepared.
    Raises ValueError for out-of-range data that is not standardised. ``abs_max``: u's and
    y's max |x| per data set and channel (:class:`ChannelStats`).
    """
    lo, hi = safe_range(params.dtype)
    out = []
    for i, (name, x) in enumerate((("u", u), ("y", y))):
        off = np.zeros(x.shape[::2])
        if params.dtype == "float32" and params.demean:
            off = x.mean(axis=1)
            x = x - off[:, None, :]
            mag = _abs_max(channel_major(x))
        else:
            mag = abs_max[i]
        bad = (mag > hi) | (mag < lo)
        mul = np.ones_like(mag)
        if bad.any() and not params.standardize:
            ds, ch = np.argwhere(bad)[0]
            raise ValueError(
                f"{name} channel {ch} of data set {ds} reaches {mag[ds, ch]:.3g} in magnitude: "
                f"with standardize=False and dtype={params.dtype} identification needs "
                f"magnitudes in [{lo:.3g}, {hi:.3g}] (its covariances would overflow or "
                f"underflow); rescale {name} or set standardize=True")
        if bad.any():
            mul = np.where(bad, np.exp2(np.floor(np.log2(mag))), 1.0)
            x = x / mul[:, None, :]
        out += [x, off, mul]
    u, u_off, u_mul, y, y_off, y_mul = out
    return u, y, (u_off, u_mul, y_off, y_mul)


def _collinear(corr: np.ndarray, tol: float):
    """Per data set: duplicate channel pairs (|corr| >= 1 - tol) and collinearity flags, from
    the channels' correlation matrices ``corr (B, c, c)``."""
    ch = corr.shape[-1]
    iu = np.triu_indices(ch, 1)
    dup = np.abs(corr[:, iu[0], iu[1]]) >= 1.0 - tol           # (B, pairs)
    flat = np.linalg.eigvalsh(corr)[:, 0] <= tol                # (B,)
    return [(int(iu[0][k]), int(iu[1][k])) for k in range(len(iu[0]))], dup, flat


def warn_collinear(stats_u: ChannelStats, stats_y: ChannelStats, tol: float) -> None:
    """Warn (:class:`CollinearWarning`) naming duplicated or collinear channels of u and y
    (their :class:`ChannelStats`)."""
    for name, st in (("u", stats_u), ("y", stats_y)):
        if st.corr.shape[-1] < 2:
            continue
        pairs, dup, flat = _collinear(st.corr, tol)
        if dup.any():
            k = int(np.argwhere(dup.any(axis=0))[0, 0])
            ds = np.flatnonzero(dup[:, k])
            warnings.warn(CollinearWarning(
                f"{name} channels {pairs[k][0]} and {pairs[k][1]} are duplicates (|correlation| "
                f">= 1 - {tol:g}) in {len(ds)} data set(s) (first {ds[:10].tolist()}); "
                f"{int(dup.any(axis=1).sum())} data set(s) have duplicated {name} channels in "
                "all: identification regularises them, but drop one of each pair"),
                stacklevel=4)
        elif flat.any():
            ds = np.flatnonzero(flat)
            warnings.warn(CollinearWarning(
                f"{name} channels are collinear (one is a linear combination of the others; "
                f"smallest eigenvalue of their correlation matrix <= {tol:g}) in {len(ds)} "
                f"data set(s) (first {ds[:10].tolist()}): identification regularises them, "
                f"but drop the redundant {name} channel"), stacklevel=4)
