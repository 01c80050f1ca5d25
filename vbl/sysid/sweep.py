"""Lag selection by the AIC of the whole one-step predictor (``lag_rule='predictor'``).

All lags ``l = 1 .. L`` (``L = lag_max``) are identified in one program on one common sample
window ``t = L .. N-K`` (``K`` = the largest horizon, ``N_e = N-K-L+1`` samples), so every lag
is scored on the same residuals. The covariances of lag ``l`` are blocks of the one Gram
matrix of the window ``z(t) = [u(t-L..t+K-1); y(t-L..t+K-1)]`` with the stack entries beyond
``l`` (past) or ``k`` (future) masked: a masked entry gets unit variance and no covariance,
so it adds only zero canonical correlations and the CVA of lag ``l`` is exact. Then

* ``n*(l)`` = argmin of Eq. (6) at lag ``l`` (as for a fixed lag);
* ``l*`` = argmin over l of ``PE(l) = AIC(n*(l)) + 2 n*(l) l (m+q)``: Eq. (6) counts
  A, B, C, D, K and R but not the ``n x l(m+q)`` coefficients of the state map
  ``mu = U p(t)``, which are fixed within one lag but grow with l. Shifting y's units adds
  the same constant ``N_e`` x 2 sum(log scale) to every lag, so the choice means the same in
  any units (unlike the paper's ``log det R < 0`` stop).

The lags are a ``vmap`` axis (no Python loop); :func:`fit_select_batch` vmaps data sets.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular

from vbl.sysid.cva import (
    CVAFit,
    _normalise,
    _order_sweep,
    _ridge,
    first_argmin,
    stack_indices,
)
from vbl.sysid.linalg import svd_thin, x64_scope
from vbl.sysid.params import CVAParams

__all__ = ["fit_select_one", "fit_select_batch", "predictor_criterion", "delays"]


def delays(lag_max: int, horizon_max: int, m: int, q: int) -> dict[str, np.ndarray]:
    """Delay of every entry of p (j of u(t-j), y(t-j)) and of f, u_f (j of y(t+j), u(t+j))."""
    return dict(p=np.r_[np.repeat(np.arange(1, lag_max + 1), m),
                        np.repeat(np.arange(1, lag_max + 1), q)],
                f=np.repeat(np.arange(horizon_max), q),
                uf=np.repeat(np.arange(horizon_max), m))


def predictor_criterion(aic_at_n, n, lag, m: int, q: int):
    """``PE(l) = AIC(n*) + 2 n* l (m+q)`` (any broadcastable shapes)."""
    with x64_scope():
        return aic_at_n + 2.0 * n * lag * (m + q)


def _mcov(g, ia, ib, wa, wb, same: bool):
    """Masked covariance block: masked entries uncorrelated (unit variance on the diagonal)."""
    s = g[ia][:, ib] * jnp.outer(wa, wb)
    return s + jnp.diag(1.0 - wa) if same else s


def _fit_lag(g, ix, dl, params, floor, lag, horizon, *, m, q, ne, n_cap, means) -> CVAFit:
    """CVA + order sweep of one (traced) lag and horizon from the common Gram matrix."""
    dt = g.dtype
    p, f = ix["p"], ix["f"]
    wp = (dl["p"] <= lag).astype(dt)
    wf = (dl["f"] < horizon).astype(dt)
    spp = _mcov(g, p, p, wp, wp, True)
    sff = _mcov(g, f, f, wf, wf, True)
    spf = _mcov(g, p, f, wp, wf, False)
    if params.method == "projected":
        uf = ix["uf"]
        wu = (dl["uf"] < horizon).astype(dt)
        lu = jnp.linalg.cholesky(_ridge(_mcov(g, uf, uf, wu, wu, True), floor))
        ap = solve_triangular(lu, _mcov(g, uf, p, wu, wp, False), lower=True)
        af = solve_triangular(lu, _mcov(g, uf, f, wu, wf, False), lower=True)
        spp = spp - ap.T @ ap
        sff = sff - af.T @ af
        spf = spf - ap.T @ af
    lp = jnp.linalg.cholesky(_ridge(spp, floor))
    lf = jnp.linalg.cholesky(_ridge(sff, floor))
    x = solve_triangular(lp, spf, lower=True)
    mw = solve_triangular(lf, x.T, lower=True).T
    ua, s, _ = svd_thin(mw)
    umat = solve_triangular(lp, ua, lower=True, trans="T").T
    umat = umat * wp[None, :]          # exact zeros on masked past entries
    n_ident = jnp.minimum(lag * (m + q), horizon * q)
    return _order_sweep(g, ix, umat, s, params, floor, m=m, q=q, ne=ne, n_cap=n_cap,
                        n_ident=n_ident, means=means, nested=True)


def fit_select_one(u, y, params: CVAParams, *, n_cap: int):
    """All lags of ``params.lags()`` on one data set ``u (N, m)``, ``y (N, q)``; pick l*.

    Returns ``(fit, index of l* (), per-lag (n* (L,), AIC(n*) (L,), log det R(n*) (L,),
    PE (L,)))``; ``fit`` is the :class:`CVAFit` at l* with the state map in the layout of
    lag L (entries beyond l* zero).
    """
    with x64_scope():
        return _fit_select_one(u, y, params, n_cap=n_cap)


def _fit_select_one(u, y, params, *, n_cap):
    dt = jnp.float32 if params.dtype == "float32" else jnp.float64
    floor = jnp.asarray(params.floor(), dt)
    u, y = u.astype(dt), y.astype(dt)
    n_samp, m = u.shape
    q = y.shape[1]
    lags = np.asarray(params.lags())
    hors = np.asarray([params.horizon_for(int(lg)) for lg in lags])
    big_l, big_k = int(lags.max()), int(hors.max())
    ne = n_samp - big_l - big_k + 1
    un, u_mean, u_scale = _normalise(u, params.demean, params.standardize)
    yn, y_mean, y_scale = _normalise(y, params.demean, params.standardize)
    w = big_l + big_k
    t = jnp.arange(ne)[:, None] + jnp.arange(w)[None, :]
    z = jnp.concatenate([un[t].reshape(ne, w * m), yn[t].reshape(ne, w * q)], axis=1)
    g = z.T @ z / ne
    ix = stack_indices(big_l, big_k, m, q)
    dl = delays(big_l, big_k, m, q)
    fit_l = functools.partial(_fit_lag, g, ix, dl, params, floor, m=m, q=q, ne=ne,
                              n_cap=n_cap, means=(u_mean, u_scale, y_mean, y_scale))
    fits = jax.vmap(fit_l)(jnp.asarray(lags), jnp.asarray(hors))
    rows = jnp.arange(len(lags))
    aic_n = fits.aic[rows, fits.n]
    ld_n = fits.logdet[rows, fits.n]
    pe = predictor_criterion(aic_n, fits.n, jnp.asarray(lags, dt), m, q)
    j = first_argmin(pe)
    best = jax.tree_util.tree_map(lambda a: a[j], fits)
    return best, j, (fits.n, aic_n, ld_n, pe)


@functools.partial(jax.jit, static_argnames=("n_cap",))
def _fit_select_batch(u, y, params, *, n_cap):
    return jax.vmap(functools.partial(_fit_select_one, params=params, n_cap=n_cap))(u, y)


def fit_select_batch(u, y, params: CVAParams, *, n_cap: int):
    """:func:`fit_select_one` vmapped over data sets ``u (B, N, m)``, ``y (B, N, q)``
    (jitted, no input checks; use :func:`vbl.sysid.identify`)."""
    with x64_scope():
        return _fit_select_batch(u, y, params, n_cap=n_cap)

