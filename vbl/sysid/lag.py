"""Validated entry point: CVA for a batch of data sets, the order by AIC and the lag.

A fixed lag (``lag > 0``) runs the predictor rule's kernel on that lag's window
(:func:`vbl.sysid.sweep.fit_batch`), n* by Eq. (6). With ``lag = 0`` the lag is chosen per
data set by ``params.lag_rule``:

* ``'predictor'`` (default, :mod:`vbl.sysid.sweep`): every l = lag_min .. lag_max in one
  program on a common sample window; n* by the order criterion pooled over these lags, l* by
  the AIC of the whole one-step predictor at n* (Eq. 6 plus the state map's coefficients).
  The same choice in any units.
* ``'paper'`` (Sec. 3.1.2): for l = 1, 2, ... identify (AIC picks n); stop at the first l
  with log det R_hat(n*) < ``logdet_stop`` (keep that l); otherwise stop when AIC(n*) at l is
  not lower than at l - 1 (keep l - 1); ``lag_max`` caps l. Each l has its own sample window
  (shapes change with l): a Python loop over the few l values, the data-set axis vmapped, and
  the loop ends early once every data set has stopped.
"""

from __future__ import annotations

import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import validate
from vbl.sysid.cva import CVAFit, fit_lags, n_identifiable
from vbl.sysid.lag_rule import select_lag as _select_lag
from vbl.sysid.linalg import x64_scope
from vbl.sysid.model import CVAModel
from vbl.sysid.params import CVAParams
from vbl.sysid.sweep import fit_batch, fit_select_batch, fit_select_one
from vbl.sysid.validate import checked, prepare_scale, warn_collinear

__all__ = ["Identification", "identify", "identify_one_fit", "select_fit", "select_lag",
           "lag_caps_for", "n_cap_for", "pad_to_history", "OrderCapWarning"]


class OrderCapWarning(UserWarning):
    """n* equals the largest order the chosen lag and horizon can identify."""


@struct.dataclass
class Identification:
    """Per-data-set result (leading axis B when the input was batched).

    ``c`` = largest order swept; ``L`` = number of lags tried.
    """

    lag: jnp.ndarray          # (B,) int32 selected l
    n: jnp.ndarray            # (B,) int32 selected n* (argmin AIC; 'predictor': pooled)
    logdet_R: jnp.ndarray     # (B,) log det R_hat(n*) (normalised units if standardize)
    aic: jnp.ndarray          # (B,) AIC(n*)
    n_samples: jnp.ndarray    # (B,) int32 N - k - l + 1
    aic_curve: jnp.ndarray    # (B, c+1) AIC(n), n = 0..c, at the selected l (inf = invalid)
    logdet_curve: jnp.ndarray  # (B, c+1) log det R_hat(n) at the selected l
    cancor: jnp.ndarray       # (B, c) canonical correlations at the selected l
    lag_aic: jnp.ndarray      # (B, L) AIC at each lag tried, at n* ('predictor': pooled
                              # n*; 'paper': each lag's own n*(l); nan = not computed)
    lag_logdet: jnp.ndarray   # (B, L) log det R_hat at each lag tried, at the same n
    lag_n: jnp.ndarray        # (B, L) int32 argmin of Eq. (6) at each lag (-1 = not computed)
    lag_criterion: jnp.ndarray  # (B, L) predictor AIC PE(l) at n* ('predictor' rule; else nan)
    n_ident: jnp.ndarray      # (B,) int32 largest order the rule can give: min(l(m+q), kq)
                              # at l ('predictor': at the smallest lag pooled)
    n_at_cap: jnp.ndarray     # (B,) bool n* == n_ident: the true order may be larger
    model: CVAModel           # batched filtering model (float32 unless asked otherwise)


def lag_caps_for(params: CVAParams, m: int, q: int) -> tuple[int, ...]:
    """Per lag of ``params.lags()``: the largest order it can identify,
    ``min(l(m+q), kq)``, at most ``n_max`` (when set)."""
    per_lag = [n_identifiable(lg, params.horizon_for(lg), m, q) for lg in params.lags()]
    return tuple(min(params.n_max, c) if params.n_max else c for c in per_lag)


def n_cap_for(params: CVAParams, m: int, q: int) -> int:
    """Largest order swept: n_max, or the most any tried lag can identify (lag_rule
    'predictor': the most every pooled lag can identify, the largest n* it can choose)."""
    caps = lag_caps_for(params, m, q)
    pooled = params.lag == 0 and params.lag_rule == "predictor"
    return min(caps) if pooled else max(caps)


def select_lag(logdet: np.ndarray, aic: np.ndarray, stop: float) -> tuple[np.ndarray, ...]:
    """:func:`vbl.sysid.lag_rule.select_lag` on per-lag results ``(B, L)`` (column j is
    l = j + 1, nan = not computed): ``(index of the chosen lag (B,), decided (B,))``."""
    with x64_scope():  # float64 comparisons, as the results are
        j, d = _select_lag(jnp.asarray(logdet), jnp.asarray(aic), stop)
    return np.asarray(j), np.asarray(d)


def pad_to_history(umat, lag: int, h: int, m: int, q: int):
    """State-map columns ``[u lags; y lags]`` (..., lag (m+q)) of lag ``lag`` in the layout
    of history length ``h`` (..., h (m+q)), zeros beyond ``lag``; NumPy in, NumPy out, else
    jnp (jit-able)."""
    xp = np if isinstance(umat, np.ndarray) else jnp

    def zeros(k: int):
        return xp.zeros(umat.shape[:-1] + (k,), umat.dtype)

    return xp.concatenate([umat[..., :lag * m], zeros((h - lag) * m), umat[..., lag * m:],
                           zeros((h - lag) * q)], axis=-1)


def identify_one_fit(u, y, params: CVAParams, *, n_cap: int):
    """The jittable core of :func:`identify` on one data set ``u (N, m)``, ``y (N, q)``
    (normalised as given; no input checks, which cannot run on traced data): the same fits,
    order cap ``n_cap`` (:func:`n_cap_for`) and lag rule, every lag fitted (no early stop).

    ``'predictor'``: :func:`vbl.sysid.sweep.fit_select_one`; ``'paper'`` or a fixed lag:
    :func:`vbl.sysid.cva.fit_lags` over ``params.lags()`` (one computation whatever the
    number of lags), the lag by :func:`vbl.sysid.lag_rule.select_lag`. Returns ``(fit, j,
    logdet (J,), aic (J,))``: the :class:`CVAFit` at the chosen lag ``params.lags()[j]`` with
    its state map in the layout of history ``max(params.lags())`` (rows beyond n* kept),
    and each lag's log det R_hat and AIC at the order the rule compares there.
    """
    with x64_scope():
        if params.lag == 0 and params.lag_rule == "predictor":
            fit, j, (_, aic, logdet, _) = fit_select_one(u, y, params, n_cap=n_cap)
            return fit, j, logdet, aic
        lags = params.lags()
        fits = fit_lags(u, y, params, lags=lags,
                        horizons=tuple(params.horizon_for(lg) for lg in lags), n_cap=n_cap)
        return select_fit(fits, params.logdet_stop)


def select_fit(fits: CVAFit, logdet_stop: float):
    """The paper's lag rule (:func:`vbl.sysid.lag_rule.select_lag`) on the per-lag fits of
    :func:`vbl.sysid.cva.fit_lags` (leading lag axis J, lags ascending from 1): ``(fit, j,
    logdet (J,), aic (J,))``, the fit at the chosen lag index ``j`` and each lag's log det
    R_hat and AIC at its n* (jittable; in the caller's precision: inside
    :func:`~vbl.sysid.linalg.x64_scope` or with 64-bit types on, float64 fits stay float64).
    """
    at_n = jnp.arange(fits.logdet.shape[-1])[None, :] == fits.n[:, None]   # (J, c+1)
    logdet = jnp.sum(jnp.where(at_n, fits.logdet, 0.0), axis=1)
    aic = jnp.sum(jnp.where(at_n, fits.aic, 0.0), axis=1)
    j = _select_lag(logdet, aic, logdet_stop)[0]
    return jax.tree_util.tree_map(lambda a: a[j], fits), j, logdet, aic


def identify(u, y, params: CVAParams | None = None, *, model_dtype=jnp.float32
             ) -> Identification:
    """Identify every data set: CVA, AIC order n* and (if ``params.lag == 0``) the lag.

    Args:
      u: inputs ``(B, N, m)`` (or one data set ``(N, m)``), any units.
      y: outputs ``(B, N, q)`` (or ``(N, q)``).
      params: :class:`CVAParams` (validated here); default: lag by the predictor AIC.
      model_dtype: floating type of the returned filtering model.
    Returns:
      :class:`Identification` (without the B axis for unbatched input).
    Raises:
      ValueError / ParamError for bad parameters or data (shapes, NaN/inf, constant
      channels, records too short, values beyond the dtype's safe range when not
      standardised) and if a result is not finite.
    Warns:
      :class:`OrderCapWarning` when n* is the largest identifiable order;
      :class:`vbl.sysid.validate.CollinearWarning` for duplicated / collinear channels.

    Runs inside :func:`vbl.sysid.linalg.x64_scope`: the same numbers whether or not
    ``jax_enable_x64`` is on globally (float fields of the result are float64 arrays).
    """
    with x64_scope():
        return _identify(u, y, params, model_dtype)


def _identify(u, y, params, model_dtype) -> Identification:
    params = validate(params if params is not None else CVAParams())
    u, y, batched, stats_u, stats_y = checked(u, y, params)
    warn_collinear(stats_u, stats_y, params.collinear_tol)
    u, y, shift = prepare_scale(u, y, params, (stats_u.abs_max, stats_y.abs_max))
    b, _, m = u.shape
    q = y.shape[2]
    if params.lag == 0 and params.lag_rule == "paper":
        out = _by_lag(u, y, params)
    else:
        out = _by_predictor(u, y, params)
    res, checks = _assemble(out, shift, m=m, q=q, batched=batched,
                            model_dtype=np.dtype(model_dtype).name)
    _raise_or_warn(jax.device_get(checks), params, model_dtype)
    return res


def _ill_conditioned(ds: np.ndarray, params: CVAParams, lag: int | None = None) -> str:
    """Message for non-finite results of data in range (so the cause is conditioning)."""
    at = f" at lag {lag}" if lag is not None else ""
    return (f"identification{at} gave non-finite results for data sets {ds[:10].tolist()}: "
            "the covariance matrices are too ill-conditioned for the regularisation floor "
            f"(dtype={params.dtype}, reg={params.reg:g}, reg_float32={params.reg_float32:g}); "
            "raise params.reg (reg_float32 for float32) or drop collinear channels")


def _raise_or_warn(checks, params: CVAParams, model_dtype) -> None:
    """Errors and the order-cap warning from :func:`_assemble`'s checks (host values):
    ``(bad, at_cap, lag, horizon, n) (5, B)`` and the model's channel ranges ``(6,)``."""
    per_set, ranges = checks
    bad, at_cap, lag, horizon, n = per_set
    if bad.any():
        raise ValueError(_ill_conditioned(np.flatnonzero(bad), params))
    fi = np.finfo(np.dtype(model_dtype))
    for name, (mean, smax, smin) in (("u", ranges[:3]), ("y", ranges[3:])):
        if mean > fi.max or smax > fi.max or smin < fi.tiny:
            raise ValueError(f"{name}'s channel means / scales (up to {mean:.3g} / "
                             f"{smax:.3g}, down to scale {smin:.3g}) do not fit "
                             f"the {fi.dtype} filtering model; pass model_dtype=jnp.float64 or "
                             f"rescale {name}")
    if at_cap.any():
        ds = np.flatnonzero(at_cap)
        i = ds[0]
        warnings.warn(OrderCapWarning(
            f"n* equals the largest identifiable order min(l(m+q), kq) (at the chosen l and "
            f"k, or with lag_rule='predictor' at the smallest lag pooled, lag_min) for "
            f"{len(ds)} data set(s) (first {ds[:10].tolist()}: l={int(lag[i])}, "
            f"k={int(horizon[i])}, n*={int(n[i])}): the true order may be larger; fix a "
            "larger lag, or raise lag_min, lag_max or horizon"), stacklevel=4)


def _by_predictor(u, y, params: CVAParams) -> dict:
    """Lag rule 'predictor' (one program for all lags, :mod:`vbl.sysid.sweep`) or a fixed lag
    (:func:`vbl.sysid.sweep.fit_batch`); the fields stay on the device."""
    n_samp, m = u.shape[1:]
    q = y.shape[2]
    lags = np.asarray(params.lags())
    hors = np.asarray([params.horizon_for(int(lg)) for lg in lags])
    n_cap = n_cap_for(params, m, q)
    if params.lag > 0:
        fit = fit_batch(u, y, params, lag=params.lag, horizon=int(hors[0]), n_cap=n_cap)
        j, per_lag = _one_lag(fit)
    else:
        fit, j, per_lag = fit_select_batch(u, y, params, n_cap=n_cap)
    # the pooled n* is at most what the shortest lag identifies: n_cap_for without n_max
    pooled_cap = n_cap_for(params.replace(n_max=0), m, q)
    return _predictor_fields(fit, j, per_lag, lags=tuple(lags.tolist()),
                             hors=tuple(hors.tolist()),
                             n_samples=n_samp - int(lags.max()) - int(hors.max()) + 1,
                             n_ident=pooled_cap)


@jax.jit
def _one_lag(fit: CVAFit):
    """A fixed lag's fits ``(B, ...)`` in the predictor rule's per-lag layout: ``(index of the
    lag (B,) = 0, (n* (B, 1), AIC(n*) (B, 1), log det R(n*) (B, 1), PE (B, 1) = nan))``."""
    rows = jnp.arange(fit.n.shape[0])
    ld, ai = fit.logdet[rows, fit.n], fit.aic[rows, fit.n]
    return jnp.zeros_like(fit.n), (fit.n[:, None], ai[:, None], ld[:, None],
                                   jnp.full_like(ai, jnp.nan)[:, None])


@functools.partial(jax.jit, static_argnames=("lags", "hors", "n_samples", "n_ident"))
def _predictor_fields(fit: CVAFit, j, per_lag, *, lags, hors, n_samples, n_ident) -> dict:
    ln, la, lld, lpe = per_lag
    rows = jnp.arange(j.shape[0])
    return dict(lag=jnp.asarray(lags, jnp.int32)[j], horizon=jnp.asarray(hors, jnp.int32)[j],
                n_ident=jnp.full(j.shape, n_ident, jnp.int32),
                n=fit.n.astype(jnp.int32),
                n_samples=jnp.full(j.shape, n_samples, jnp.int32),
                logdet_R=lld[rows, j], aic=la[rows, j], aic_curve=fit.aic,
                logdet_curve=fit.logdet, cancor=fit.cancor, lag_aic=la, lag_logdet=lld,
                lag_n=ln.astype(jnp.int32), lag_criterion=lpe, U=fit.U, A=fit.A, B=fit.B,
                C=fit.C, D=fit.D, R=fit.R, u_mean=fit.u_mean, u_scale=fit.u_scale,
                y_mean=fit.y_mean, y_scale=fit.y_scale)


def _by_lag(u, y, params: CVAParams) -> dict:
    """Lag rule 'paper': a loop over lags, each vmapped over data sets."""
    b, n_samp, m = u.shape
    q = y.shape[2]
    lags = params.lags()
    c = n_cap_for(params, m, q)
    h = max(lags)
    fits: list[CVAFit] = []
    ld = np.full((b, len(lags)), np.nan)
    ai = np.full((b, len(lags)), np.nan)
    ln = np.full((b, len(lags)), -1, np.int32)
    for j, lag in enumerate(lags):
        fit = jax.device_get(fit_batch(u, y, params, lag=lag,
                                       horizon=params.horizon_for(lag), n_cap=c))
        idx = np.arange(b)
        ld[:, j] = fit.logdet[idx, fit.n]
        ai[:, j] = fit.aic[idx, fit.n]
        ln[:, j] = fit.n
        bad = ~np.isfinite(ld[:, j]) | ~np.isfinite(ai[:, j])
        if bad.any():
            raise ValueError(_ill_conditioned(np.flatnonzero(bad), params, lag))
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
    hor = np.asarray([params.horizon_for(int(lg)) for lg in lag_arr])
    out = dict(lag=lag_arr, horizon=hor, n=pick(lambda j, f: f.n).astype(np.int32),
               n_ident=np.minimum(lag_arr * (m + q), hor * q).astype(np.int32),  # per data set
               n_samples=(n_samp - hor - lag_arr + 1).astype(np.int32),
               logdet_R=ld[np.arange(b), chosen], aic=ai[np.arange(b), chosen],
               lag_aic=ai, lag_logdet=ld, lag_n=ln, lag_criterion=np.full(ld.shape, np.nan),
               U=pick(lambda j, f: pad_to_history(np.asarray(f.U), lags[j], h, m, q)))
    for k in ("aic_curve", "logdet_curve", "cancor", "A", "B", "C", "D", "R", "u_mean",
              "u_scale", "y_mean", "y_scale"):
        key = {"aic_curve": "aic", "logdet_curve": "logdet"}.get(k, k)
        out[k] = pick(lambda j, f, key=key: getattr(f, key))
    return out


@functools.partial(jax.jit, static_argnames=("m", "q", "batched", "model_dtype"))
def _assemble(out: dict, shift, *, m: int, q: int, batched: bool, model_dtype: str):
    """Result and model (raw units restored) in one program, so the fields stay on the device;
    returns ``(Identification, checks)``, ``checks`` = the few values the host needs for its
    errors and warning (:func:`_raise_or_warn`)."""
    n = out["n"].astype(jnp.int32)
    c = out["A"].shape[-1]
    umat = out["U"] * (jnp.arange(c)[None, :, None] < n[:, None, None])   # mu masked beyond n*
    n_id = out["n_ident"].astype(jnp.int32)
    at_cap = n == n_id
    bad = ~jnp.isfinite(out["logdet_R"]) | ~jnp.isfinite(out["aic"])
    for k in ("U", "A", "B", "C", "D", "R"):
        bad |= ~jnp.isfinite(out[k]).reshape(bad.shape[0], -1).all(1)
    u_off, u_mul, y_off, y_mul = shift
    raw = dict(u_mean=u_off + u_mul * out["u_mean"], u_scale=u_mul * out["u_scale"],
               y_mean=y_off + y_mul * out["y_mean"], y_scale=y_mul * out["y_scale"])
    # two arrays (one transfer each): per data set, and the model's channel ranges
    ranges = [jnp.max(jnp.abs(raw["u_mean"])), jnp.max(raw["u_scale"]), jnp.min(raw["u_scale"]),
              jnp.max(jnp.abs(raw["y_mean"])), jnp.max(raw["y_scale"]), jnp.min(raw["y_scale"])]
    checks = (jnp.stack([bad, at_cap, out["lag"], out["horizon"], n]).astype(jnp.int32),
              jnp.stack(ranges).astype(jnp.float64))
    md = jnp.dtype(model_dtype)
    model = CVAModel(U=umat.astype(md), A=out["A"].astype(md), B=out["B"].astype(md),
                     C=out["C"].astype(md), D=out["D"].astype(md), R=out["R"].astype(md), n=n,
                     lag=out["lag"].astype(jnp.int32),
                     **{k: v.astype(md) for k, v in raw.items()})
    res = Identification(
        lag=out["lag"].astype(jnp.int32), n=n, logdet_R=out["logdet_R"], aic=out["aic"],
        n_samples=out["n_samples"].astype(jnp.int32), aic_curve=out["aic_curve"],
        logdet_curve=out["logdet_curve"], cancor=out["cancor"], lag_aic=out["lag_aic"],
        lag_logdet=out["lag_logdet"], lag_n=out["lag_n"].astype(jnp.int32),
        lag_criterion=out["lag_criterion"], n_ident=n_id, n_at_cap=at_cap, model=model)
    if not batched:
        res = jax.tree_util.tree_map(lambda a: a[0], res)
    return res, checks
