"""Batched Canonical Variate Analysis, Eqs. (2)-(6) of the paper.

One data set is ``u (N, m)``, ``y (N, q)``; :func:`fit_batch` vmaps :func:`fit_one` over a
leading data-set axis. Per data set (0-based time, ``t = l .. N-k``, ``N_e = N-k-l+1`` samples):

* past    ``p(t) = [u(t-1); ...; u(t-l); y(t-1); ...; y(t-l)]``   (l(m+q),)
* future  ``f(t) = [y(t); ...; y(t+k-1)]``                         (kq,)
* future inputs ``u_f(t) = [u(t); ...; u(t+k-1)]``                 (km,)

All covariances come from one Gram matrix of the window ``z(t) = [u(t-l..t+k-1); y(t-l..t+k-1)]``.
With ``method='projected'`` the future inputs are projected out of p and f first
(``S_ab|u = S_ab - S_au S_uu^-1 S_ub``). Whitening uses Cholesky factors
(``S = L L^T``, ``S^-1/2 := L^-1``), so ``L_p^-1 S_pf L_f^-T = U_aux S_aux V_aux^T`` (Eq. 4)
and ``U = U_aux^T L_p^-1``; ``mu(t) = [I_n 0] U p(t)`` (Eq. 5). One SVD serves every n: the
least-squares fit of Eq. (2) for order n masks the state components beyond n, vmapped over n.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.scipy.linalg import cho_solve, solve_triangular

from vbl.sysid.aic import aic as aic_fn
from vbl.sysid.linalg import svd_thin, x64_scope
from vbl.sysid.params import CVAParams

__all__ = ["CVAFit", "fit_one", "fit_batch", "n_identifiable", "stack_indices", "first_argmin"]


@struct.dataclass
class CVAFit:
    """Result of CVA on one data set at one lag (leading data-set axis when batched).

    Shapes use ``c = n_cap`` (orders swept 0..c), ``dp = l(m+q)``. Normalised units: the
    data after mean removal / standardisation (``u_n = (u - u_mean) / u_scale``).
    """

    cancor: jnp.ndarray      # (c,) canonical correlations S_aux, descending (0-padded)
    logdet: jnp.ndarray      # (c+1,) log det R_hat(n), n = 0..c (output residual covariance)
    aic: jnp.ndarray         # (c+1,) AIC(n); +inf where n < n_min or n > identifiable
    n: jnp.ndarray           # () int32 n* = argmin AIC
    U: jnp.ndarray           # (c, dp) rows of U = U_aux^T S_pp^-1/2 (0-padded)
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


def stack_indices(lag: int, horizon: int, m: int, q: int) -> dict[str, np.ndarray]:
    """Positions of p(t), p(t+1), f(t), u_f(t), u(t), y(t) in the window z(t)."""
    L = lag + horizon

    def ui(off: int) -> list[int]:
        return [(off + lag) * m + c for c in range(m)]

    def yi(off: int) -> list[int]:
        return [m * L + (off + lag) * q + c for c in range(q)]

    def cat(parts: list[list[int]]) -> np.ndarray:
        return np.asarray(sum(parts, []), dtype=np.int32)

    return dict(
        p=cat([ui(-j) for j in range(1, lag + 1)] + [yi(-j) for j in range(1, lag + 1)]),
        p1=cat([ui(1 - j) for j in range(1, lag + 1)] + [yi(1 - j) for j in range(1, lag + 1)]),
        f=cat([yi(j) for j in range(horizon)]),
        uf=cat([ui(j) for j in range(horizon)]),
        u0=cat([ui(0)]),
        y0=cat([yi(0)]),
    )


def _ridge(s: jnp.ndarray, floor) -> jnp.ndarray:
    """S + floor * mean(diag S) * I (the regularisation floor)."""
    d = s.shape[-1]
    scale = jnp.maximum(jnp.trace(s) / d, jnp.finfo(s.dtype).tiny)
    return s + floor * scale * jnp.eye(d, dtype=s.dtype)


def _normalise(x: jnp.ndarray, demean: bool, standardize: bool):
    mean = jnp.mean(x, axis=0) if demean else jnp.zeros(x.shape[1], x.dtype)
    scale = jnp.std(x, axis=0) if standardize else jnp.ones(x.shape[1], x.dtype)
    return (x - mean) / scale, mean, scale


def fit_one(u: jnp.ndarray, y: jnp.ndarray, params: CVAParams, *, lag: int, horizon: int,
            n_cap: int) -> CVAFit:
    """CVA + order sweep on one data set ``u (N, m)``, ``y (N, q)`` (pure, jit/vmap-able).

    Computes in ``params.dtype`` whether or not ``jax_enable_x64`` is on globally (64-bit
    types are switched on for the duration of the computation, :func:`x64_scope`).
    """
    with x64_scope():
        return _fit_one(u, y, params, lag=lag, horizon=horizon, n_cap=n_cap)


def _fit_one(u: jnp.ndarray, y: jnp.ndarray, params: CVAParams, *, lag: int, horizon: int,
             n_cap: int) -> CVAFit:
    dt = jnp.float32 if params.dtype == "float32" else jnp.float64
    floor = jnp.asarray(params.floor(), dt)
    u = u.astype(dt)
    y = y.astype(dt)
    N, m = u.shape
    q = y.shape[1]
    L = lag + horizon
    ne = N - L + 1
    un, u_mean, u_scale = _normalise(u, params.demean, params.standardize)
    yn, y_mean, y_scale = _normalise(y, params.demean, params.standardize)

    # Window matrix Z (ne, L(m+q)) and its Gram matrix: every covariance is a block of G.
    t = jnp.arange(ne)[:, None] + jnp.arange(L)[None, :]
    z = jnp.concatenate([un[t].reshape(ne, L * m), yn[t].reshape(ne, L * q)], axis=1)
    g = z.T @ z / ne
    ix = stack_indices(lag, horizon, m, q)
    p, f = ix["p"], ix["f"]
    spp, sff, spf = g[p][:, p], g[f][:, f], g[p][:, f]
    if params.method == "projected":
        uf = ix["uf"]
        lu = jnp.linalg.cholesky(_ridge(g[uf][:, uf], floor))
        ap = solve_triangular(lu, g[uf][:, p], lower=True)
        af = solve_triangular(lu, g[uf][:, f], lower=True)
        spp = spp - ap.T @ ap
        sff = sff - af.T @ af
        spf = spf - ap.T @ af

    # Eq. (4) with Cholesky whitening.
    lp = jnp.linalg.cholesky(_ridge(spp, floor))
    lf = jnp.linalg.cholesky(_ridge(sff, floor))
    x = solve_triangular(lp, spf, lower=True)                 # L_p^-1 S_pf
    mw = solve_triangular(lf, x.T, lower=True).T              # ... L_f^-T
    ua, s, _ = svd_thin(mw)                                   # (dp, r), (r,)
    umat = solve_triangular(lp, ua, lower=True, trans="T").T  # U = U_aux^T L_p^-1, (r, dp)
    return _order_sweep(g, ix, umat, s, params, floor, m=m, q=q, ne=ne, n_cap=n_cap,
                        n_ident=n_identifiable(lag, horizon, m, q),
                        means=(u_mean, u_scale, y_mean, y_scale))


def first_argmin(a: jnp.ndarray) -> jnp.ndarray:
    """Index (int32) of the first minimum of a 1-D array (``jnp.argmin`` for finite input).

    Written with ``min`` and ``where``: ``jnp.argmin`` fails to lower when 64-bit types are
    switched on only inside a caller's ``jit(vmap(...))``.
    """
    idx = jnp.arange(a.shape[0], dtype=jnp.int32)
    return jnp.min(jnp.where(a == jnp.min(a), idx, a.shape[0] - 1)).astype(jnp.int32)


def _nested_logdet(sxx, sxy, syy, floor, *, m: int, c: int):
    """log det R_hat(n) (c+1,) and R_hat(n) (c+1, q, q) for n = 0..c regressors mu_1..mu_n
    beside u(t): one Cholesky of the covariance of [u(t); mu(t)] (rows of L^-1 S_xy are the
    successive reductions of the residual covariance)."""
    order = np.r_[c:c + m, 0:c]                               # [u(t); mu_1..mu_c]
    lx = jnp.linalg.cholesky(_ridge(sxx[order][:, order], floor))
    w = solve_triangular(lx, sxy[order], lower=True)          # (m+c, q)
    red = jnp.cumsum(w[:, :, None] * w[:, None, :], axis=0)   # (m+c, q, q)
    rs = jax.vmap(lambda r: _ridge(syy - r, floor))(red[m - 1:])
    logdet = 2.0 * jnp.sum(jnp.log(jnp.diagonal(jnp.linalg.cholesky(rs), axis1=-2,
                                                axis2=-1)), axis=-1)
    return logdet, rs


def _order_sweep(g, ix, umat, s, params, floor, *, m, q, ne, n_cap, n_ident, means,
                 nested: bool = False) -> CVAFit:
    """Eq. (2) for every order n = 0..n_cap from the Gram matrix ``g`` and the state map
    ``umat`` (r, dp), canonical correlations ``s`` (r,); AIC (Eq. 6) picks n* among
    ``n_min <= n <= n_ident``.

    ``nested=False``: one masked Cholesky per order (O(c^4)); ``nested=True``: the residual
    covariances of all orders from one Cholesky of the regressors ordered [u(t); mu(t)]
    (regressing on a prefix of them, O(c^3)); equal up to the regularisation floor.
    """
    dt = g.dtype
    p = ix["p"]
    r = s.shape[0]
    dp = p.shape[0]
    if r >= n_cap:
        umat, s = umat[:n_cap], s[:n_cap]
    else:
        umat = jnp.concatenate([umat, jnp.zeros((n_cap - r, dp), dt)], axis=0)
        s = jnp.concatenate([s, jnp.zeros((n_cap - r,), dt)])

    # Covariance of [mu(t); mu(t+1); u(t); y(t)] = T G T^T.
    eye = jnp.eye(g.shape[0], dtype=dt)
    tm = jnp.concatenate([umat @ eye[p], umat @ eye[ix["p1"]], eye[ix["u0"]], eye[ix["y0"]]])
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
        return jnp.linalg.cholesky(_ridge(sm, floor)), w

    def logdet_r(n):
        lx, w = masked(n)
        wy = solve_triangular(lx, sxy * w[:, None], lower=True)
        rr = _ridge(syy - wy.T @ wy, floor)
        return 2.0 * jnp.sum(jnp.log(jnp.diag(jnp.linalg.cholesky(rr)))), rr

    ns = jnp.arange(c + 1)
    if nested:
        logdet, rs = _nested_logdet(sxx, sxy, syy, floor, m=m, c=c)
    else:
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


def fit_batch(u: jnp.ndarray, y: jnp.ndarray, params: CVAParams, *, lag: int, horizon: int,
              n_cap: int) -> CVAFit:
    """:func:`fit_one` vmapped over data sets: ``u (B, N, m)``, ``y (B, N, q)`` (jitted).

    No input checks: use :func:`vbl.sysid.identify` for validated entry. Pass NumPy arrays
    (or arrays made with 64-bit types on) to keep float64 data exact when
    ``jax_enable_x64`` is off: the call runs inside :func:`x64_scope`.
    """
    with x64_scope():
        return _fit_batch(u, y, params, lag=lag, horizon=horizon, n_cap=n_cap)


@functools.partial(jax.jit, static_argnames=("lag", "horizon", "n_cap"))
def _fit_batch(u, y, params, *, lag, horizon, n_cap):
    fn = functools.partial(_fit_one, params=params, lag=lag, horizon=horizon, n_cap=n_cap)
    return jax.vmap(fn)(u, y)
