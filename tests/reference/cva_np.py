"""Float64 NumPy reference of CVA (Eqs. 2-6), written independently of vbl.sysid.

Deliberately different numerics from the JAX code: explicit stacks built sample by sample,
symmetric inverse square roots from ``eigh``, ``lstsq`` per order. Same definitions:
0-based samples t = l .. N-k; p(t) = [u(t-1..t-l); y(t-1..t-l)], f(t) = [y(t..t+k-1)],
u_f(t) = [u(t..t+k-1)]; covariances divide by N_e = N-k-l+1; 'projected' conditions the
past and future covariances on u_f; R_hat(n) is the covariance of the LS residual of
y(t) on [mu_n(t); u(t)]; AIC(n) = N_e log det R_hat(n) + 2 lambda(n).
"""

from __future__ import annotations

import numpy as np


def _inv_sqrt(s: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh(s)
    return (v / np.sqrt(w)) @ v.T


def _ridge(s: np.ndarray, reg: float) -> np.ndarray:
    return s + reg * np.trace(s) / len(s) * np.eye(len(s))


def cva_reference(u: np.ndarray, y: np.ndarray, lag: int, horizon: int, *,
                  method: str = "projected", n_min: int = 1, n_max: int | None = None,
                  count: str = "larimore", reg: float = 1e-10, demean: bool = True,
                  standardize: bool = True) -> dict:
    """CVA of one data set ``u (N, m)``, ``y (N, q)``. Returns a dict with ``cancor``,
    ``logdet`` (n = 0..n_max), ``aic``, ``n`` (argmin), ``U`` (rows of the state map)."""
    u = np.array(u, np.float64)
    y = np.array(y, np.float64)
    if demean:
        u = u - u.mean(0)
        y = y - y.mean(0)
    if standardize:
        u = u / u.std(0)
        y = y / y.std(0)
    n_samp, m = u.shape
    q = y.shape[1]
    ts = range(lag, n_samp - horizon + 1)
    ne = len(ts)
    P, P1, F, UF, U0, Y0 = [], [], [], [], [], []
    for t in ts:
        P.append(np.concatenate([u[t - i] for i in range(1, lag + 1)]
                                + [y[t - i] for i in range(1, lag + 1)]))
        P1.append(np.concatenate([u[t + 1 - i] for i in range(1, lag + 1)]
                                 + [y[t + 1 - i] for i in range(1, lag + 1)]))
        F.append(np.concatenate([y[t + i] for i in range(horizon)]))
        UF.append(np.concatenate([u[t + i] for i in range(horizon)]))
        U0.append(u[t])
        Y0.append(y[t])
    P, P1, F, UF, U0, Y0 = map(np.asarray, (P, P1, F, UF, U0, Y0))
    Pc, Fc = P, F
    if method == "projected":
        # residuals of P and F after least squares on the future inputs
        Pc = P - UF @ np.linalg.lstsq(UF, P, rcond=None)[0]
        Fc = F - UF @ np.linalg.lstsq(UF, F, rcond=None)[0]
    elif method != "paper":
        raise ValueError(method)
    spp = _ridge(Pc.T @ Pc / ne, reg)
    sff = _ridge(Fc.T @ Fc / ne, reg)
    spf = Pc.T @ Fc / ne
    wp = _inv_sqrt(spp)
    ua, s, _ = np.linalg.svd(wp @ spf @ _inv_sqrt(sff))
    r = min(P.shape[1], F.shape[1])
    umap = ua.T @ wp
    n_top = r if n_max is None else min(n_max, r)
    logdet, aic = [], []
    for n in range(n_top + 1):
        X = np.concatenate([P @ umap[:n].T, U0], axis=1)
        coef = np.linalg.lstsq(X, Y0, rcond=None)[0]
        e = Y0 - X @ coef
        R = e.T @ e / ne
        ld = np.linalg.slogdet(R)[1]
        lam = (n * (2 * q + m) + q * m + q * (q + 1) / 2 if count == "larimore"
               else n * (q + m) + q * m)
        logdet.append(ld)
        aic.append(ne * ld + 2 * lam if n >= n_min else np.inf)
    aic = np.asarray(aic)
    n_star = int(np.argmin(aic))
    X = np.concatenate([P @ umap[:n_star].T, U0], axis=1)
    T = np.concatenate([P1 @ umap[:n_star].T, Y0], axis=1)
    theta = np.linalg.lstsq(X, T, rcond=None)[0].T
    return dict(cancor=s[:r], logdet=np.asarray(logdet), aic=aic, n=n_star, U=umap[:r],
                A=theta[:n_star, :n_star], n_samples=ne)
