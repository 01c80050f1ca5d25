"""Batched Canonical Variate Analysis, Eqs. (2)-(6) of the paper.

One data set is ``u (N, m)``, ``y (N, q)``; :func:`fit_lags` fits several lags of it in one
fixed-shape computation (``vmap`` over the lags): the in-program identification of the
learners and of Tables 1 and 3. (One lag of many data sets, as :func:`vbl.sysid.identify`
runs it: :func:`vbl.sysid.sweep.fit_one` / ``fit_batch``, the predictor rule's kernel.) Per
data set and lag l with horizon k
(0-based time, ``t = l .. N-k``, ``N_e = N-k-l+1`` samples):

* past    ``p(t) = [u(t-1); ...; u(t-l); y(t-1); ...; y(t-l)]``   (l(m+q),)
* future  ``f(t) = [y(t); ...; y(t+k-1)]``                         (kq,)
* future inputs ``u_f(t) = [u(t); ...; u(t+k-1)]``                 (km,)

All covariances come from one Gram matrix of the window ``z(t) = [p(t); u_f(t); f(t)]`` over
the lag's samples (columns of the zero-padded record taken as slices, no index gathers).
:func:`fit_lags` lays every lag out at the largest lag ``L`` and horizon ``K`` (the window
of lag L) and pads: a lag's unused past / future entries get unit variance and zero
covariance with everything else, which adds only zero canonical correlations, and its
samples are those of its own window (a mask over t). With ``method='projected'`` the future
inputs are projected out of p and f first (``S_ab|u = S_ab - S_au S_uu^-1 S_ub``). Whitening
uses Cholesky factors (``S = L L^T``, ``S^-1/2 := L^-1``), so ``L_p^-1 S_pf L_f^-T = U_aux
S_aux V_aux^T`` (Eq. 4) and ``U = U_aux^T L_p^-1``; ``mu(t) = [I_n 0] U p(t)`` (Eq. 5). One
SVD serves every n: the least-squares fit of Eq. (2) for order n masks the state components
beyond n, vmapped over n. Orders beyond a lag's ``min(l(m+q), kq)`` are invalid.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.scipy.linalg import cho_solve, solve_triangular

from vbl.sysid.aic import aic as aic_fn
from vbl.sysid.linalg import svd_thin, x64_scope
from vbl.sysid.params import CVAParams

__all__ = ["CVAFit", "fit_lags", "n_identifiable", "first_argmin", "ridge_floor", "normalise"]


@struct.dataclass
class CVAFit:
    """Result of CVA on one data set at one lag (leading data-set axis when batched; leading
    lag axis from :func:`fit_lags`).

    Shapes use ``c = n_cap`` (orders swept 0..c), ``dp = h(m+q)`` with ``h`` the history
    length (the lag for :func:`vbl.sysid.sweep.fit_one`, the largest lag for
    :func:`fit_lags`). Normalised units: the data after mean removal / standardisation
    (``u_n = (u - u_mean) / u_scale``).
    """

    cancor: jnp.ndarray      # (c,) canonical correlations S_aux, descending (0-padded)
    logdet: jnp.ndarray      # (c+1,) log det R_hat(n), n = 0..c (output residual covariance)
    aic: jnp.ndarray         # (c+1,) AIC(n); +inf where n < n_min or n > identifiable
    n: jnp.ndarray           # () int32 n* = argmin AIC
    U: jnp.ndarray           # (c, dp) rows of U = U_aux^T S_pp^-1/2 (0-padded; columns
                             # [u(t-1..t-h); y(t-1..t-h)], zero beyond the lag)
    A: jnp.ndarray           # (c, c) Theta blocks at n* (zero beyond n*)
    B: jnp.ndarray           # (c, m)
    C: jnp.ndarray           # (q, c)
    D: jnp.ndarray           # (q, m)
    R: jnp.ndarray           # (q, q) output residual covariance at n*
    u_mean: jnp.ndarray      # (m,)
    u_scale: jnp.ndarray     # (m,)
    y_mean: jnp.ndarray      # (q,)
    y_scale: jnp.ndarray     # (q,)


def n_identifiable(lag: int, horizon: int, m: int, q: int) -> int:
    """Number of canonical correlations min(l(m+q), kq): the largest order CVA can give."""
    return min(lag * (m + q), horizon * q)


def ridge_floor(s: jnp.ndarray, floor, pad=0) -> jnp.ndarray:
    """S + floor * mean(diag S) * I (the regularisation floor); the mean leaves out ``pad``
    (may be traced) padded entries of unit diagonal and zero covariance, so a padded
    matrix gets the floor of its unpadded block."""
    d = s.shape[-1]
    scale = jnp.maximum((jnp.trace(s) - pad) / (d - pad), jnp.finfo(s.dtype).tiny)
    return s + floor * scale * jnp.eye(d, dtype=s.dtype)


def _ridge_padded(s: jnp.ndarray, v: jnp.ndarray, floor) -> jnp.ndarray:
    """:func:`ridge_floor` of the entries of ``s`` where ``v`` (0/1) is 1 (``s`` zero
    elsewhere), unit variance on the padded entries:
    ``s + diag(1 - v) + floor * (tr s / sum v) * I``."""
    scale = jnp.maximum(jnp.trace(s) / jnp.sum(v), jnp.finfo(s.dtype).tiny)
    return s + jnp.diag(1.0 - v) + floor * scale * jnp.eye(s.shape[-1], dtype=s.dtype)


def normalise(x: jnp.ndarray, demean: bool, standardize: bool):
    """(x - mean) / scale over time (axis 0) of x (T, d), with mean (d,) (zeros without
    ``demean``) and scale (d,) (the std; ones without ``standardize``)."""
    mean = jnp.mean(x, axis=0) if demean else jnp.zeros(x.shape[1], x.dtype)
    scale = jnp.std(x, axis=0) if standardize else jnp.ones(x.shape[1], x.dtype)
    return (x - mean) / scale, mean, scale


def fit_lags(u: jnp.ndarray, y: jnp.ndarray, params: CVAParams, *, lags: tuple[int, ...],
             horizons: tuple[int, ...], n_cap: int,
             lag_caps: tuple[int, ...] | None = None) -> CVAFit:
    """CVA + order sweep of one data set ``u (N, m)``, ``y (N, q)`` at every lag of ``lags``
    (with its horizon of ``horizons``), as one computation at the sizes of the largest lag
    and horizon, vmapped over the lags (one traced copy whatever the number of lags).

    Returns the :class:`CVAFit` s with a leading lag axis ``(J, ...)``, ``J = len(lags)``; the
    state maps in the layout of history ``h = max(lags)`` (columns beyond a lag zero). Each
    lag is fitted on its own sample window ``t = l .. N-k``, as a fit at that lag alone
    (equal to float rounding). Orders 0..``n_cap`` are swept at every lag; with
    ``lag_caps`` (one order cap per lag, each <= ``n_cap``) lag j is fitted as
    ``fit_lags`` of that lag alone with ``n_cap=lag_caps[j]`` would (components and orders
    beyond its cap zero / invalid, the order sweep's regularisation floor that of its own cap).
    Pure, jit/vmap-able, in ``params.dtype`` (:func:`x64_scope`).
    """
    caps = tuple(int(c) for c in lag_caps) if lag_caps is not None else (n_cap,) * len(lags)
    if len(caps) != len(lags) or max(caps) > n_cap:
        raise ValueError(f"lag_caps={lag_caps} must give one cap <= n_cap={n_cap} per lag "
                         f"of {tuple(lags)}")
    with x64_scope():
        return _fit_lags(u, y, params, lags=tuple(int(lg) for lg in lags),
                         horizons=tuple(int(k) for k in horizons), n_cap=n_cap, caps=caps)


def _window_layout(big_l: int, big_k: int, m: int, q: int):
    """Column layout of the window ``z(t) = [p(t); u_f(t); f(t)]`` at lag ``big_l``, horizon
    ``big_k``: ``(dp, offset of u_f, offset of f, P1)``, ``P1 (dp, width)`` the 0/1 matrix
    taking ``p(t+1) = [u(t..t-L+1); y(t..t-L+1)]`` from ``z(t)`` (``p1 = P1 z``)."""
    dp = big_l * (m + q)
    o_uf, o_f = dp, dp + big_k * m
    width = o_f + big_k * q
    p1 = np.zeros((dp, width))
    for c in range(m):
        p1[c, o_uf + c] = 1.0                                     # u(t)
        for i in range(1, big_l):
            p1[i * m + c, (i - 1) * m + c] = 1.0                  # u(t-i)
    for c in range(q):
        p1[big_l * m + c, o_f + c] = 1.0                          # y(t)
        for i in range(1, big_l):
            p1[big_l * m + i * q + c, big_l * m + (i - 1) * q + c] = 1.0
    return dp, o_uf, o_f, p1


def _fit_lags(u, y, params, *, lags, horizons, n_cap, caps) -> CVAFit:
    dt = jnp.float32 if params.dtype == "float32" else jnp.float64
    floor = jnp.asarray(params.floor(), dt)
    u = u.astype(dt)
    y = y.astype(dt)
    n_samp, m = u.shape
    q = y.shape[1]
    big_l, big_k = max(lags), max(horizons)
    un, u_mean, u_scale = normalise(u, params.demean, params.standardize)
    yn, y_mean, y_scale = normalise(y, params.demean, params.standardize)
    dp, o_uf, o_f, p1 = _window_layout(big_l, big_k, m, q)

    # z(t) for every t = 0..N-1 from the zero-padded records (slices): delays L..1, then 0..-(K-1)
    def delayed(x, delays):
        xp = jnp.concatenate([jnp.zeros((big_l, x.shape[1]), dt), x,
                              jnp.zeros((big_k, x.shape[1]), dt)])
        return jnp.concatenate([xp[big_l - j:big_l - j + n_samp] for j in delays], axis=1)

    past, fut = range(1, big_l + 1), range(0, -big_k, -1)
    z = jnp.concatenate([delayed(un, past), delayed(yn, past), delayed(un, fut),
                         delayed(yn, fut)], axis=1)

    # per lag: its samples, its past / future entries (0/1), N_e, identifiable order
    la, ka = np.asarray(lags), np.asarray(horizons)
    t = np.arange(n_samp)
    per_lag = dict(
        tmask=((t >= la[:, None]) & (t <= n_samp - ka[:, None])).astype(float),
        vp=np.concatenate([np.repeat(np.arange(1, big_l + 1)[None] <= la[:, None], m, 1),
                           np.repeat(np.arange(1, big_l + 1)[None] <= la[:, None], q, 1)], 1),
        vu=np.repeat(np.arange(big_k)[None] < ka[:, None], m, 1),
        vf=np.repeat(np.arange(big_k)[None] < ka[:, None], q, 1),
        ne=n_samp - ka - la + 1,
        # identifiable orders, at most the lag's cap; the cap's shortfall from n_cap
        n_ident=np.minimum(np.minimum(la * (m + q), ka * q), caps),
        pad=n_cap - np.asarray(caps))
    per_lag = {k: jnp.asarray(v, jnp.int32 if k in ("ne", "n_ident", "pad") else dt)
               for k, v in per_lag.items()}
    means = (u_mean, u_scale, y_mean, y_scale)
    p, uf, f = slice(0, dp), slice(o_uf, o_f), slice(o_f, z.shape[1])

    def one_lag(pl):
        g = (z * pl["tmask"][:, None]).T @ z / pl["ne"].astype(dt)
        vp, vu, vf = pl["vp"], pl["vu"], pl["vf"]
        spp = g[p, p] * jnp.outer(vp, vp)
        sff = g[f, f] * jnp.outer(vf, vf)
        spf = g[p, f] * jnp.outer(vp, vf)
        if params.method == "projected":
            lu = jnp.linalg.cholesky(_ridge_padded(g[uf, uf] * jnp.outer(vu, vu), vu, floor))
            ap = solve_triangular(lu, g[uf, p] * jnp.outer(vu, vp), lower=True)
            af = solve_triangular(lu, g[uf, f] * jnp.outer(vu, vf), lower=True)
            spp = spp - ap.T @ ap
            sff = sff - af.T @ af
            spf = spf - ap.T @ af
        # Eq. (4) with Cholesky whitening.
        lp = jnp.linalg.cholesky(_ridge_padded(spp, vp, floor))
        lf = jnp.linalg.cholesky(_ridge_padded(sff, vf, floor))
        x = solve_triangular(lp, spf, lower=True)                 # L_p^-1 S_pf
        mw = solve_triangular(lf, x.T, lower=True).T              # ... L_f^-T
        ua, s, _ = svd_thin(mw)                                   # (dp, r), (r,)
        umat = solve_triangular(lp, ua, lower=True, trans="T").T  # U = U_aux^T L_p^-1, (r, dp)
        # the lag's own components: the first n_ident (the rest are the padding's zeros)
        keep = (jnp.arange(s.shape[0]) < pl["n_ident"]).astype(dt)
        umat = umat * keep[:, None] * vp[None, :]
        return _order_sweep(g, umat, s * keep, p1, params, floor, m=m, q=q, o_uf=o_uf,
                            o_f=o_f, ne=pl["ne"], n_cap=n_cap, n_ident=pl["n_ident"],
                            pad=pl["pad"], means=means)

    return jax.vmap(one_lag)(per_lag)


def first_argmin(a: jnp.ndarray) -> jnp.ndarray:
    """Index (int32) of the first minimum of a 1-D array (``jnp.argmin`` for finite input).

    One variadic reduction over ``(value, index)`` pairs with initial values of ``a``'s own
    dtype: ``jnp.argmin`` / ``lax.argmin`` fail to lower when 64-bit types are switched on
    only inside a caller's ``jit(vmap(...))`` (their initial value takes the global default
    dtype), and an index found by comparing ``a`` with ``min(a)`` can miss every entry when
    XLA fuses the computation of ``a`` into both and rounds the two copies differently.
    """
    def pick(x, y):
        take = (x[0] < y[0]) | ((x[0] == y[0]) & (x[1] < y[1]))
        return jnp.where(take, x[0], y[0]), jnp.where(take, x[1], y[1])

    idx = jnp.arange(a.shape[0], dtype=jnp.int32)
    init = (jnp.asarray(jnp.inf, a.dtype), jnp.asarray(a.shape[0] - 1, jnp.int32))
    return jax.lax.reduce((a, idx), init, pick, (0,))[1]


def _order_sweep(g, umat, s, p1, params, floor, *, m, q, o_uf, o_f, ne, n_cap, n_ident,
                 pad, means) -> CVAFit:
    """Eq. (2) for every order n = 0..n_cap from the window's Gram matrix ``g`` (layout of
    :func:`_window_layout`: ``p(t)`` first, ``u(t)`` at ``o_uf``, ``y(t)`` at ``o_f``, ``P1``
    selecting ``p(t+1)``) and the state map ``umat`` (r, dp), canonical correlations ``s``
    (r,): one masked Cholesky per order; AIC (Eq. 6) picks n* among
    ``n_min <= n <= n_ident``. The floor of each masked Cholesky is that of a sweep to
    ``n_cap - pad`` (the fit's own cap; ``pad`` may be traced)."""
    dt = g.dtype
    r, dp = umat.shape
    if r >= n_cap:
        umat, s = umat[:n_cap], s[:n_cap]
    else:
        umat = jnp.concatenate([umat, jnp.zeros((n_cap - r, dp), dt)], axis=0)
        s = jnp.concatenate([s, jnp.zeros((n_cap - r,), dt)])

    # Covariance of [mu(t); mu(t+1); u(t); y(t)] = T G T^T.
    width = g.shape[0]
    eye = np.eye(width)
    tm = jnp.concatenate([jnp.pad(umat, ((0, 0), (0, width - dp))),
                          umat @ jnp.asarray(p1, dt),
                          jnp.asarray(eye[o_uf:o_uf + m], dt), jnp.asarray(eye[o_f:o_f + q], dt)])
    cov = tm @ g @ tm.T
    c = n_cap
    xi = np.r_[0:c, 2 * c:2 * c + m]                          # regressors [mu(t); u(t)]
    yi = np.arange(2 * c + m, 2 * c + m + q)                 # y(t)
    ti = np.r_[c:2 * c, 2 * c + m:2 * c + m + q]              # targets [mu(t+1); y(t)]
    sxx = cov[xi][:, xi]
    sxy = cov[xi][:, yi]
    syy = cov[yi][:, yi]

    def masked(n):
        w = jnp.concatenate([(jnp.arange(c) < n).astype(dt), jnp.ones(m, dt)])
        sm = sxx * jnp.outer(w, w) + jnp.diag(1.0 - w)
        return jnp.linalg.cholesky(ridge_floor(sm, floor, pad)), w

    def logdet_r(n):
        lx, w = masked(n)
        wy = solve_triangular(lx, sxy * w[:, None], lower=True)
        rr = ridge_floor(syy - wy.T @ wy, floor)
        return 2.0 * jnp.sum(jnp.log(jnp.diag(jnp.linalg.cholesky(rr)))), rr

    ns = jnp.arange(c + 1)
    logdet, rs = jax.vmap(logdet_r)(ns)
    a = aic_fn(logdet, ns, ne, m, q, params.param_count)
    # an order whose residual covariance is numerically singular (NaN) is not identifiable
    valid = (ns >= params.n_min) & (ns <= n_ident) & jnp.isfinite(logdet)
    a = jnp.where(valid, a, jnp.inf)
    n_star = first_argmin(a)

    # Theta of Eq. (2) at n*: [mu(t+1); y(t)] = Theta [mu(t); u(t)].
    lx, w = masked(n_star)
    theta = cho_solve((lx, True), cov[xi][:, ti] * w[:, None]).T
    rows = jnp.concatenate([(jnp.arange(c) < n_star).astype(dt), jnp.ones(q, dt)])
    theta = theta * rows[:, None]
    return CVAFit(cancor=jnp.clip(s, 0.0, 1.0), logdet=logdet, aic=a, n=n_star, U=umat,
                  A=theta[:c, :c], B=theta[:c, c:], C=theta[c:, :c], D=theta[c:, c:],
                  R=rs[n_star], u_mean=means[0], u_scale=means[1], y_mean=means[2],
                  y_scale=means[3])
