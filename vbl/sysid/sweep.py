"""CVA of one data set from one Gram matrix: the kernel of :func:`vbl.sysid.identify`.

:func:`fit_select_batch` (``lag_rule='predictor'``) identifies every lag ``lag_min ..
lag_max`` on one common sample window, each lag's covariances taken as blocks of the one
Gram matrix of that window, and picks the order ``n*`` by Eq. (6) pooled over the lags
(:func:`pooled_criterion`) and the lag ``l*`` by the AIC of the whole one-step predictor.
:func:`fit_one` and :func:`fit_batch` fit one lag with the order by Eq. (6) (what
``identify`` runs with a fixed lag or the paper's lag rule), the same kernel on that lag's
window. Data sets run in chunks of :data:`CHUNK` (one compiled ``vmap`` per chunk), so one
compiled program serves every batch size.

See docs/sysid.md, "Lag selection" (the criteria, and how the sweep is computed).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.lax.linalg import cholesky, triangular_solve
from jax.scipy.linalg import solve_triangular

from vbl.sysid.aic import aic as aic_fn
from vbl.sysid.aic import param_count
from vbl.sysid.batching import in_chunks
from vbl.sysid.cva import CVAFit, first_argmin, normalise, ridge_floor
from vbl.sysid.gram import hankel_gram
from vbl.sysid.linalg import eigh_desc, svd_thin, x64_scope
from vbl.sysid.params import CVAParams

__all__ = ["fit_one", "fit_batch", "fit_select_one", "fit_select_batch", "predictor_criterion",
           "pooled_criterion", "hankel_gram", "logdet_spd", "CHUNK"]

#: Data sets per chunk of :func:`fit_select_batch` and :func:`fit_batch` (a ``vmap`` inside
#: a chunk, chunks in sequence, :func:`vbl.sysid.batching.in_chunks`): small enough for a
#: chunk's working set to stay in the cache (the cost per identification is the same at 1,024
#: and 4,096 data sets, ``benchmarks/cva_throughput.py``), large enough to amortise the
#: per-operation overhead of the vmapped program (the chunk sizes measured:
#: docs/findings/cva_cost.md, "Kept by measurement").
CHUNK = 64


def predictor_criterion(aic_at_n, n, lag, m: int, q: int):
    """``PE(l) = AIC(n*) + 2 n* l (m+q)`` (any broadcastable shapes)."""
    with x64_scope():
        return aic_at_n + 2.0 * n * lag * (m + q)


def _cumsum0(a: jnp.ndarray) -> jnp.ndarray:
    """Cumulative sum over axis 0 as one product with a lower-triangular matrix of ones
    (XLA's CPU cumsum is a reduce-window, much slower for these short axes)."""
    k = a.shape[0]
    tri = jnp.asarray(np.tril(np.ones((k, k))), a.dtype)
    return (tri @ a.reshape(k, -1)).reshape(a.shape)


def logdet_spd(a: jnp.ndarray) -> jnp.ndarray:
    """log det of symmetric positive definite ``a (..., q, q)`` as the sum of the log pivots
    of Gaussian elimination (an unrolled loop over the q pivots in elementwise operations:
    for the many q x q matrices of the order sweep, much cheaper than a LAPACK call each).
    NaN (or -inf) when ``a`` is not positive definite, as with a Cholesky factor."""
    q = a.shape[-1]
    out = jnp.zeros(a.shape[:-2], a.dtype)
    for k in range(q):
        piv = a[..., 0, 0]
        out = out + jnp.log(piv)
        if k < q - 1:
            a = a[..., 1:, 1:] - a[..., 1:, :1] * a[..., :1, 1:] / piv[..., None, None]
    return out


def _chol(s: jnp.ndarray) -> jnp.ndarray:
    """Lower Cholesky factor of symmetric ``s`` from its lower triangle (NaN if not positive
    definite), without ``jnp.linalg.cholesky``'s symmetrising copy ``(s + s^T) / 2``."""
    return cholesky(s, symmetrize_input=False)


def _lag_cva(g4, params, floor, *, big_l, lag, horizon, m, q, ne, n_cap) -> dict:
    """CVA + order sweep of lag ``lag`` at its own sizes from the Gram matrix ``g4``
    ``(w, d, w, d)`` (block ``(a, b)``: window offsets a and b, ``d = m + q``): the
    per-order curves (padded to ``n_cap`` orders) and what :func:`_lag_fit` needs to build
    the model at any order.

    Every stack is a slice of ``g4`` (no gather): the past ``p(t)`` = offsets
    ``big_l - l .. big_l - 1`` (oldest first, ``[u; y]`` per offset), ``p(t+1)`` the same
    shifted by one, the future ``f(t)`` / ``u_f(t)`` = the y / u channels of offsets
    ``big_l .. big_l + k - 1``, ``[u(t); y(t)]`` = offset ``big_l``. The order of p's entries
    changes neither the canonical correlations nor U (whose columns are permuted back to
    ``p(t)``'s layout by :func:`_lag_fit`).
    """
    d = m + q
    lo, hi, k = big_l - lag, big_l, horizon
    dp = lag * d
    al, uu, yy = slice(None), slice(0, m), slice(m, d)

    def blk(a0, a1, ca, b0, b1, cb):
        x = g4[a0:a1, ca, b0:b1, cb]
        return x.reshape((a1 - a0) * x.shape[1], (b1 - b0) * x.shape[3])

    spp = blk(lo, hi, al, lo, hi, al)
    sff = blk(hi, hi + k, yy, hi, hi + k, yy)
    spf = blk(lo, hi, al, hi, hi + k, yy)
    if params.method == "projected":
        lu = _chol(ridge_floor(blk(hi, hi + k, uu, hi, hi + k, uu), floor))
        a = solve_triangular(lu, jnp.concatenate([blk(hi, hi + k, uu, lo, hi, al),
                                                  blk(hi, hi + k, uu, hi, hi + k, yy)], 1),
                             lower=True)
        ap, af = a[:, :dp], a[:, dp:]
        spp = spp - ap.T @ ap
        sff = sff - af.T @ af
        spf = spf - ap.T @ af
    lp = _chol(ridge_floor(spp, floor))
    lf = _chol(ridge_floor(sff, floor))
    mw = triangular_solve(lf, solve_triangular(lp, spf, lower=True), left_side=False,
                          lower=True, transpose_a=True)                 # Lp^-1 S_pf Lf^-T
    r = min(mw.shape)                            # canonical correlations
    c = min(n_cap, r)                            # orders this lag can give (<= n_cap)
    if mw.shape[0] <= mw.shape[1]:               # U_aux, S_aux^2 from M M^T (see module doc)
        s2, ua = eigh_desc(mw @ mw.T)
        s = jnp.sqrt(jnp.maximum(s2, 0.0))
    else:
        ua, s, _ = svd_thin(mw)
    umat = triangular_solve(lp, ua[:, :c].T, left_side=False, lower=True)  # (c, dp)
    n_ident = min(lag * (m + q), horizon * q)

    # Covariances of mu(t) = U p(t), mu(t+1) = U p(t+1), x0 = [u(t); y(t)]: offsets lo..hi.
    g_p = blk(lo, hi, al, lo, hi + 1, al)                               # (dp, dp + d)
    ug = umat @ g_p                                                      # (c, dp + d)
    s_mm, s_mm1, s_mx = ug[:, :dp] @ umat.T, ug[:, d:] @ umat.T, ug[:, dp:]
    s_xm1 = blk(hi, hi + 1, al, lo + 1, hi + 1, al) @ umat.T             # (d, c)
    s_x0 = g4[hi, :, hi, :]
    # regressors [u(t); mu(t)], targets [mu(t+1); y(t)] (the last q columns: output y(t))
    sxx = jnp.block([[s_x0[:m, :m], s_mx[:, :m].T], [s_mx[:, :m], s_mm]])
    sxt = jnp.block([[s_xm1[:m], s_x0[:m, m:]], [s_mm1, s_mx[:, m:]]])
    syy = s_x0[m:, m:]
    lx = _chol(ridge_floor(sxx, floor))
    # U S_pp U^T carries rounding errors up to ~ dp eps |U_i|^2 max row sum |S_pp| per state;
    # where S_pp is (nearly) singular (duplicated or collinear channels) |U_i| is huge, the
    # errors exceed the regularisation floor and the factorisation fails: then (only then)
    # that bound is added to the states' variances.
    bound = dp * jnp.finfo(umat.dtype).eps * jnp.max(jnp.sum(jnp.abs(g_p[:, :dp]), axis=1))
    lx_safe = _chol(ridge_floor(sxx + jnp.diag(jnp.concatenate(
        [jnp.zeros(m, umat.dtype), bound * jnp.sum(umat * umat, axis=1)])), floor))
    lx = jnp.where(jnp.all(jnp.isfinite(lx)), lx, lx_safe)
    z = solve_triangular(lx, sxt, lower=True)                            # (m+c, c+q)
    wy = z[:, c:]                                                        # L^-1 S_xy
    red = _cumsum0(wy[:, :, None] * wy[:, None, :])[m - 1:]    # n = 0..c
    rs = jax.vmap(lambda r: ridge_floor(syy - r, floor))(red)
    logdet = logdet_spd(rs)
    # orders beyond c add zero states: the residual stays that of order c
    logdet = jnp.concatenate([logdet, jnp.broadcast_to(logdet[-1], (n_cap - c,))])
    rs = jnp.concatenate([rs, jnp.broadcast_to(rs[-1], (n_cap - c, q, q))])
    ns = jnp.arange(n_cap + 1)
    valid = (ns >= params.n_min) & (ns <= n_ident) & jnp.isfinite(logdet)
    a = jnp.where(valid, aic_fn(logdet, ns, ne, m, q, params.param_count), jnp.inf)
    return dict(cancor=jnp.pad(jnp.clip(s[:c], 0.0, 1.0), (0, n_cap - c)), logdet=logdet,
                aic=a, valid=valid, rs=rs, umat=umat, lx=lx, z=z)


def _lag_fit(st: dict, n, *, big_l, lag, m, q, n_cap, means) -> CVAFit:
    """The :class:`CVAFit` of one lag's :func:`_lag_cva` result ``st`` at order ``n``: Theta
    of Eq. (2) regressed on the prefix ``[u(t); mu_1..mu_n]`` of the regressors, whose
    Cholesky factor is the leading block of ``st['lx']`` (``L^-T`` applied to the rows of
    ``L^-1 S_xt`` up to the prefix is zero beyond it); the state map in the layout of lag
    ``big_l`` (zero beyond l), fields padded to ``n_cap`` orders."""
    umat, lx, z = st["umat"], st["lx"], st["z"]
    dt = z.dtype
    c, d = umat.shape[0], m + q
    wmask = jnp.concatenate([jnp.ones(m, dt), (jnp.arange(c) < n).astype(dt)])
    theta = solve_triangular(lx, z * wmask[:, None], lower=True, trans="T").T  # (c+q, m+c)
    keep = jnp.concatenate([(jnp.arange(c) < n).astype(dt), jnp.ones(q, dt)])
    theta = theta * keep[:, None]
    pad = n_cap - c
    big_a = jnp.pad(theta[:c, m:], ((0, pad), (0, pad)))
    big_b = jnp.pad(theta[:c, :m], ((0, pad), (0, 0)))
    big_c = jnp.pad(theta[c:, m:], ((0, 0), (0, pad)))
    # columns to p(t)'s layout [u(t-1..t-l); y(t-1..t-l)], zero beyond l, rows to n_cap
    ur = umat.reshape(c, lag, d)[:, ::-1]
    ur = jnp.concatenate([ur, jnp.zeros((c, big_l - lag, d), dt)], axis=1)
    u_big = jnp.pad(jnp.concatenate([ur[:, :, :m].reshape(c, big_l * m),
                                     ur[:, :, m:].reshape(c, big_l * q)], 1),
                    ((0, pad), (0, 0)))
    return CVAFit(cancor=st["cancor"], logdet=st["logdet"], aic=st["aic"],
                  n=jnp.asarray(n, jnp.int32), U=u_big, A=big_a, B=big_b, C=big_c,
                  D=theta[c:, :m], R=st["rs"][n], u_mean=means[0], u_scale=means[1],
                  y_mean=means[2], y_scale=means[3])


def pooled_criterion(logdet, valid, ne: int, m: int, q: int, params: CVAParams):
    """The order criterion of the predictor rule: ``sum_l [N_e log det R_l(n) +
    order_penalty lambda(n)]`` over the lags tried, from the per-lag curves ``logdet``
    ``(L, c+1)`` and their ``valid`` masks (inf where some lag cannot give n)."""
    with x64_scope():
        ns = jnp.arange(logdet.shape[-1])
        lam = param_count(ns, m, q, params.param_count)
        crit = jnp.sum(ne * logdet + params.order_penalty * lam, axis=0)
        return jnp.where(jnp.all(valid, axis=0), crit, jnp.inf)


def fit_select_one(u, y, params: CVAParams, *, n_cap: int):
    """All lags of ``params.lags()`` on one data set ``u (N, m)``, ``y (N, q)``; pick the
    pooled n* and l*.

    Returns ``(fit, index of l* (), per-lag (argmin of Eq. (6) at each lag (L,), AIC(n*)
    (L,), log det R(n*) (L,), PE(l) at n* (L,)))``; ``fit`` is the :class:`CVAFit` at l* and
    order n* with the state map in the layout of lag L (entries beyond l* zero).
    """
    with x64_scope():
        return _fit_select_one(u, y, params, n_cap=n_cap)


def _gram_window(u, y, params, big_l: int, big_k: int):
    """The normalised record's Gram matrix of the window of lag ``big_l`` and horizon
    ``big_k``: ``(g4 (w, d, w, d) / N_e, floor, means (u_mean, u_scale, y_mean, y_scale),
    N_e)``, ``w = big_l + big_k``, ``d = m + q``, in ``params.dtype``."""
    dt = jnp.float32 if params.dtype == "float32" else jnp.float64
    u, y = u.astype(dt), y.astype(dt)
    ne = u.shape[0] - big_l - big_k + 1
    un, u_mean, u_scale = normalise(u, params.demean, params.standardize)
    yn, y_mean, y_scale = normalise(y, params.demean, params.standardize)
    w, d = big_l + big_k, u.shape[1] + y.shape[1]
    g4 = (hankel_gram(jnp.concatenate([un, yn], axis=1), w) / ne).reshape(w, d, w, d)
    return g4, jnp.asarray(params.floor(), dt), (u_mean, u_scale, y_mean, y_scale), ne


def fit_one(u, y, params: CVAParams, *, lag: int, horizon: int, n_cap: int) -> CVAFit:
    """CVA + order sweep of one data set ``u (N, m)``, ``y (N, q)`` at one lag and horizon
    (window ``t = lag .. N-horizon``), n* = argmin of Eq. (6) over orders 0..``n_cap``
    (pure, jit/vmap-able; the kernel of the predictor rule on one lag, :func:`_lag_cva`).

    Computes in ``params.dtype`` whether or not ``jax_enable_x64`` is on globally (64-bit
    types are switched on for the duration of the computation, :func:`x64_scope`).
    """
    with x64_scope():
        m, q = u.shape[1], y.shape[1]
        g4, floor, means, ne = _gram_window(u, y, params, lag, horizon)
        st = _lag_cva(g4, params, floor, big_l=lag, lag=lag, horizon=horizon, m=m, q=q,
                      ne=ne, n_cap=n_cap)
        return _lag_fit(st, first_argmin(st["aic"]), big_l=lag, lag=lag, m=m, q=q,
                        n_cap=n_cap, means=means)


def fit_batch(u, y, params: CVAParams, *, lag: int, horizon: int, n_cap: int,
              chunk: int = CHUNK) -> CVAFit:
    """:func:`fit_one` vmapped over data sets ``u (B, N, m)``, ``y (B, N, q)``: one jitted
    ``vmap`` per chunk of ``chunk`` data sets (:func:`vbl.sysid.batching.in_chunks`).

    No input checks: use :func:`vbl.sysid.identify` for validated entry. Pass NumPy arrays
    (or arrays made with 64-bit types on) to keep float64 data exact when
    ``jax_enable_x64`` is off: the call runs inside :func:`x64_scope`.
    """
    with x64_scope():
        return in_chunks(functools.partial(_fit_batch, params=params, lag=lag,
                                           horizon=horizon, n_cap=n_cap), u, y, chunk)


@functools.partial(jax.jit, static_argnames=("lag", "horizon", "n_cap"))
def _fit_batch(u, y, params, *, lag, horizon, n_cap):
    return jax.vmap(functools.partial(fit_one, params=params, lag=lag, horizon=horizon,
                                      n_cap=n_cap))(u, y)


def _fit_select_one(u, y, params, *, n_cap):
    m, q = u.shape[1], y.shape[1]
    lags = np.asarray(params.lags())
    hors = np.asarray([params.horizon_for(int(lg)) for lg in lags])
    big_l, big_k = int(lags.max()), int(hors.max())
    g4, floor, means, ne = _gram_window(u, y, params, big_l, big_k)
    dt = g4.dtype
    kw = dict(big_l=big_l, m=m, q=q, n_cap=n_cap)
    stats = [_lag_cva(g4, params, floor, lag=int(lg), horizon=int(k), ne=ne, **kw)
             for lg, k in zip(lags, hors, strict=True)]
    logdet = jnp.stack([st["logdet"] for st in stats])                   # (L, c+1)
    aic = jnp.stack([st["aic"] for st in stats])
    n = first_argmin(pooled_criterion(logdet, jnp.stack([st["valid"] for st in stats]), ne,
                                      m, q, params))
    fits = [_lag_fit(st, n, lag=int(lg), means=means, **kw)
            for st, lg in zip(stats, lags, strict=True)]
    fits = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *fits)
    n_lag = jax.vmap(first_argmin)(aic)
    pe = predictor_criterion(aic[:, n], n, jnp.asarray(lags, dt), m, q)
    j = first_argmin(pe)
    best = jax.tree_util.tree_map(lambda a: a[j], fits)
    return best, j, (n_lag, aic[:, n], logdet[:, n], pe)


@functools.partial(jax.jit, static_argnames=("n_cap",))
def _fit_select_batch(u, y, params, *, n_cap):
    return jax.vmap(functools.partial(_fit_select_one, params=params, n_cap=n_cap))(u, y)


def fit_select_batch(u, y, params: CVAParams, *, n_cap: int, chunk: int = CHUNK):
    """:func:`fit_select_one` over data sets ``u (B, N, m)``, ``y (B, N, q)``: one jitted
    ``vmap`` per chunk of ``chunk`` data sets (:func:`vbl.sysid.batching.in_chunks`; no input
    checks: use :func:`vbl.sysid.identify`)."""
    with x64_scope():
        return in_chunks(functools.partial(_fit_select_batch, params=params, n_cap=n_cap),
                         u, y, chunk)
