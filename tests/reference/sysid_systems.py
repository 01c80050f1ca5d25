"""Random stable discrete-time linear systems of known order, simulated in NumPy (float64).

Used by the CVA tests and benchmark as ground truth. Poles are drawn with magnitude in
``radius`` (uniform), complex-conjugate pairs with angle in ``angle`` (rad) or real with a
random sign; ``A`` is the real block-diagonal form in a random basis, ``B, C, D`` standard
normal (``D`` scaled by ``d_scale``). Inputs are white N(0, 1); measurement noise is white
with std ``noise`` x the std of each noise-free output channel.
"""

from __future__ import annotations

import numpy as np


def random_poles(rng: np.random.Generator, n: int, radius=(0.5, 0.95),
                 angle=(0.3, 2.8), p_complex: float = 0.5,
                 min_separation: float = 0.0) -> np.ndarray:
    """``n`` stable poles (conjugate pairs kept together), complex array (n,).

    Draws are rejected until every two poles are at least ``min_separation`` apart (an
    order that finite data can resolve).
    """
    while True:
        poles = _draw_poles(rng, n, radius, angle, p_complex)
        d = np.abs(poles[:, None] - poles[None, :]) + np.eye(n) * 10.0
        if d.min() >= min_separation:
            return poles


def _draw_poles(rng, n, radius, angle, p_complex) -> np.ndarray:
    poles: list[complex] = []
    while len(poles) < n:
        r = rng.uniform(*radius)
        if n - len(poles) >= 2 and rng.random() < p_complex:
            th = rng.uniform(*angle)
            poles += [r * np.exp(1j * th), r * np.exp(-1j * th)]
        else:
            poles.append(complex(r * rng.choice([-1.0, 1.0])))
    return np.asarray(poles)


def realise(rng: np.random.Generator, poles: np.ndarray, m: int, q: int,
            d_scale: float = 1.0) -> tuple[np.ndarray, ...]:
    """A random real (A, B, C, D) with eigenvalues ``poles``."""
    n = len(poles)
    a0 = np.zeros((n, n))
    i = 0
    while i < n:
        z = poles[i]
        if abs(z.imag) > 0:
            a0[i:i + 2, i:i + 2] = [[z.real, z.imag], [-z.imag, z.real]]
            i += 2
        else:
            a0[i, i] = z.real
            i += 1
    t = rng.standard_normal((n, n)) + 2.0 * np.eye(n)
    a = t @ a0 @ np.linalg.inv(t)
    return (a, rng.standard_normal((n, m)), rng.standard_normal((q, n)),
            d_scale * rng.standard_normal((q, m)))


def simulate_batch(rng: np.random.Generator, orders: np.ndarray, N: int, m: int, q: int,
                   noise: float, burn_in: int = 200, **kw):
    """Simulate one random system per entry of ``orders``.

    Returns ``u (B, N, m)``, ``y (B, N, q)`` and ``poles``: list of (n_b,) complex arrays.
    """
    orders = np.asarray(orders)
    b, n_pad = len(orders), int(orders.max())
    a = np.zeros((b, n_pad, n_pad))
    bm = np.zeros((b, n_pad, m))
    cm = np.zeros((b, q, n_pad))
    dm = np.zeros((b, q, m))
    poles = []
    for i, n in enumerate(orders):
        pl = random_poles(rng, int(n), **{k: v for k, v in kw.items() if k != "d_scale"})
        ai, bi, ci, di = realise(rng, pl, m, q, kw.get("d_scale", 1.0))
        a[i, :n, :n], bm[i, :n], cm[i, :, :n], dm[i] = ai, bi, ci, di
        poles.append(pl)
    u = rng.standard_normal((b, N + burn_in, m))
    x = np.zeros((b, n_pad))
    y = np.zeros((b, N + burn_in, q))
    for k in range(N + burn_in):
        y[:, k] = np.einsum("bqn,bn->bq", cm, x) + np.einsum("bqm,bm->bq", dm, u[:, k])
        x = np.einsum("bij,bj->bi", a, x) + np.einsum("bnm,bm->bn", bm, u[:, k])
    u, y = u[:, burn_in:], y[:, burn_in:]
    y = y + noise * y.std(axis=1, keepdims=True) * rng.standard_normal(y.shape)
    return u, y, poles


def pole_error(true: np.ndarray, est: np.ndarray) -> float:
    """Largest distance from a true pole to its matched estimated pole (optimal matching)."""
    from scipy.optimize import linear_sum_assignment

    if len(true) != len(est):
        return float("inf")
    cost = np.abs(true[:, None] - est[None, :])
    r, c = linear_sum_assignment(cost)
    return float(cost[r, c].max())
