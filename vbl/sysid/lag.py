"""Validated entry point: CVA for a batch of data sets with the lag rule of Sec. 3.1.2.

Lag rule (per data set, all data sets at once): for l = 1, 2, ... identify (AIC picks n);
stop at the first l with log det R_hat(n*) < ``logdet_stop`` (keep that l); otherwise stop
when AIC(n*) at l is not lower than at l - 1 (keep l - 1); ``lag_max`` caps l. A Python loop
runs over the few l values (each l changes shapes); the data-set axis is vmapped, and the loop
ends early once every data set has stopped.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import validate
from vbl.sysid.cva import CVAFit, fit_batch, n_identifiable
from vbl.sysid.linalg import x64_scope
from vbl.sysid.model import CVAModel
from vbl.sysid.params import CVAParams
from vbl.sysid.validate import check_data

__all__ = ["Identification", "identify", "select_lag", "n_cap_for"]


@struct.dataclass
class Identification:
    """Per-data-set result (leading axis B when the input was batched).

    ``c`` = largest order swept; ``L`` = number of lags tried.
    """

    lag: jnp.ndarray          # (B,) int32 selected l
    n: jnp.ndarray            # (B,) int32 selected n* (argmin AIC at the selected l)
    logdet_R: jnp.ndarray     # (B,) log det R_hat(n*) (normalised units if standardize)
    aic: jnp.ndarray          # (B,) AIC(n*)
    n_samples: jnp.ndarray    # (B,) int32 N - k - l + 1
    aic_curve: jnp.ndarray    # (B, c+1) AIC(n), n = 0..c, at the selected l (inf = invalid)
    logdet_curve: jnp.ndarray  # (B, c+1) log det R_hat(n) at the selected l
    cancor: jnp.ndarray       # (B, c) canonical correlations at the selected l
    lag_aic: jnp.ndarray      # (B, L) AIC(n*) for each lag tried (nan = not computed)
    lag_logdet: jnp.ndarray   # (B, L) log det R_hat(n*) for each lag tried
    model: CVAModel           # batched filtering model (float32 unless asked otherwise)


def n_cap_for(params: CVAParams, m: int, q: int) -> int:
    """Largest order swept: n_max, or the most any tried lag can identify."""
    ident = max(n_identifiable(lg, params.horizon_for(lg), m, q) for lg in params.lags())
    return min(params.n_max, ident) if params.n_max else ident


def select_lag(logdet: np.ndarray, aic: np.ndarray, stop: float) -> tuple[np.ndarray, ...]:
    """Lag rule on per-lag results ``(B, L)`` (column j is l = j + 1, nan = not computed).

    Returns ``(index of the chosen lag (B,), decided (B,))``.
    """
    b, nl = logdet.shape
    chosen = np.full(b, nl - 1)
    decided = np.zeros(b, bool)
    for j in range(nl):
        if np.isnan(logdet[:, j]).all():
            break
        hit = ~decided & (logdet[:, j] < stop)
        chosen[hit], decided[hit] = j, True
        if j > 0:
            worse = ~decided & (aic[:, j] >= aic[:, j - 1])
            chosen[worse], decided[worse] = j - 1, True
    return chosen, decided


def _pad_u(umat: np.ndarray, lag: int, h: int, m: int, q: int) -> np.ndarray:
    """Map U columns for lag l into the history layout of length h (zeros beyond l)."""
    out = np.zeros(umat.shape[:-1] + (h * (m + q),), umat.dtype)
    out[..., :lag * m] = umat[..., :lag * m]
    out[..., h * m:h * m + lag * q] = umat[..., lag * m:]
    return out


def identify(u, y, params: CVAParams | None = None, *, model_dtype=jnp.float32
             ) -> Identification:
    """Identify every data set: CVA, AIC order n* and (if ``params.lag == 0``) the lag rule.

    Args:
      u: inputs ``(B, N, m)`` (or one data set ``(N, m)``), any units.
      y: outputs ``(B, N, q)`` (or ``(N, q)``).
      params: :class:`CVAParams` (validated here).
      model_dtype: floating type of the returned filtering model.
    Returns:
      :class:`Identification` (without the B axis for unbatched input).
    Raises:
      ValueError / ParamError for bad parameters or data (shapes, NaN/inf, constant
      channels, records too short for the lags and horizon) and if a result is not finite.

    Runs inside :func:`vbl.sysid.linalg.x64_scope`: the same numbers whether or not
    ``jax_enable_x64`` is on globally (float fields of the result are float64 arrays).
    """
    with x64_scope():
        return _identify(u, y, params, model_dtype)


def _identify(u, y, params, model_dtype) -> Identification:
    params = validate(params if params is not None else CVAParams())
    u, y, batched = check_data(u, y, params)
    b, _, m = u.shape
    q = y.shape[2]
    lags = params.lags()
    c = n_cap_for(params, m, q)
    h = max(lags)
    fits: list[CVAFit] = []
    ld = np.full((b, len(lags)), np.nan)
    ai = np.full((b, len(lags)), np.nan)
    uj, yj = jnp.asarray(u), jnp.asarray(y)
    for j, lag in enumerate(lags):
        fit = jax.device_get(fit_batch(uj, yj, params, lag=lag,
                                       horizon=params.horizon_for(lag), n_cap=c))
        idx = np.arange(b)
        ld[:, j] = fit.logdet[idx, fit.n]
        ai[:, j] = fit.aic[idx, fit.n]
        bad = ~np.isfinite(ld[:, j]) | ~np.isfinite(ai[:, j])
        if bad.any():
            raise ValueError(f"identification at lag {lag} gave non-finite log det R for data "
                             f"sets {np.flatnonzero(bad)[:10].tolist()}: ill-conditioned data; "
                             "raise params.reg or check the data")
        fits.append(fit)
        if len(lags) > 1 and select_lag(ld, ai, params.logdet_stop)[1].all():
            break
    if len(lags) > 1:
        chosen, _ = select_lag(ld, ai, params.logdet_stop)
    else:
        chosen = np.zeros(b, int)

    def pick(get):
        stack = np.stack([np.asarray(get(j, f)) for j, f in enumerate(fits)])
        return stack[chosen, np.arange(b)]

    lag_arr = np.asarray(lags, np.int32)[chosen]
    n = pick(lambda j, f: f.n).astype(np.int32)
    umat = pick(lambda j, f: _pad_u(np.asarray(f.U), lags[j], h, m, q))
    umat = umat * (np.arange(c)[None, :, None] < n[:, None, None])   # mu masked beyond n*
    md = model_dtype

    def cast(a):
        return jnp.asarray(a, md)

    model = CVAModel(U=cast(umat), A=cast(pick(lambda j, f: f.A)), B=cast(pick(lambda j, f: f.B)),
                     C=cast(pick(lambda j, f: f.C)), D=cast(pick(lambda j, f: f.D)),
                     R=cast(pick(lambda j, f: f.R)), n=jnp.asarray(n), lag=jnp.asarray(lag_arr),
                     u_mean=cast(pick(lambda j, f: f.u_mean)),
                     u_scale=cast(pick(lambda j, f: f.u_scale)),
                     y_mean=cast(pick(lambda j, f: f.y_mean)),
                     y_scale=cast(pick(lambda j, f: f.y_scale)))
    n_samples = np.asarray([u.shape[1] - params.horizon_for(int(lg)) - int(lg) + 1
                            for lg in lag_arr], np.int32)
    res = Identification(
        lag=jnp.asarray(lag_arr), n=jnp.asarray(n),
        logdet_R=jnp.asarray(ld[np.arange(b), chosen]), aic=jnp.asarray(ai[np.arange(b), chosen]),
        n_samples=jnp.asarray(n_samples),
        aic_curve=jnp.asarray(pick(lambda j, f: f.aic)),
        logdet_curve=jnp.asarray(pick(lambda j, f: f.logdet)),
        cancor=jnp.asarray(pick(lambda j, f: f.cancor)),
        lag_aic=jnp.asarray(ai), lag_logdet=jnp.asarray(ld), model=model)
    if not batched:
        res = jax.tree_util.tree_map(lambda a: a[0], res)
    return res
