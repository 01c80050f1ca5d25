"""Gram matrix of a sliding window of a multichannel record, from its lag products.

The window ``Z[t] = [x(t); x(t+1); ...; x(t+w-1)]``, ``t = 0 .. N-w`` (``ne = N-w+1`` rows),
of ``x (N, d)`` has a block-Toeplitz Gram matrix up to edge terms: block ``(b+s, b)`` is
``F[s] + sum_{j<b} [x(ne+j+s) x(ne+j)^T - x(j+s) x(j)^T]`` with the lag products
``F[s] = sum_{t<ne} x(t+s) x(t)^T``. Everything here is slices, reshapes and a few matrix
products (no index gathers, which XLA's CPU backend runs element by element).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

__all__ = ["lag_products", "block_toeplitz", "hankel_gram", "BLOCK"]

#: Samples per row of the blocked record in :func:`lag_products`: the ``w`` products of
#: ``(d x ne) (ne x d)``, whose ``d x d`` outputs keep XLA's CPU matrix product far from its
#: speed, become one product with ``(w/BLOCK + 1) BLOCK d x BLOCK d`` outputs (the block
#: sizes measured: docs/findings/cva_cost.md, "Kept by measurement").
BLOCK = 6


def lag_products(x: jnp.ndarray, w: int, block: int = BLOCK) -> jnp.ndarray:
    """``F[s] = sum_{t=0}^{ne-1} x(t+s) x(t)^T`` for ``s = 0 .. w-1`` (``ne = N-w+1``):
    ``(w, d, d)`` from ``x (N, d)``.

    The record in rows of ``block`` samples, ``Y[a] = x(a block .. a block + block - 1)``: the
    products of ``[Y[a]; Y[a+1]; ...; Y[a+J-1]]`` with ``Y0[a]`` (``Y`` with the samples
    ``t >= ne`` zeroed) over ``a`` hold every ``x(t+s) x(t)^T`` once; ``F[s]`` sums the
    ``block`` of them at distance ``s`` (a skew by reshaping).
    """
    n, d = x.shape
    ne = n - w + 1
    nb = -(-ne // block)                                    # rows of Y0
    nj = (block + w - 2) // block + 1                       # row offsets reaching s < w
    tot = (nb + nj) * block
    xp = jnp.concatenate([x, jnp.zeros((tot - n, d), x.dtype)])
    keep = jnp.asarray(np.arange(nb * block) < ne, x.dtype)[:, None]
    y0 = (xp[:nb * block] * keep).reshape(nb, block * d)
    yb = xp.reshape(nb + nj, block * d)
    ycat = jnp.concatenate([yb[j:j + nb] for j in range(nj)], axis=1)     # (nb, nj block d)
    k = nj * block
    q = (ycat.T @ y0).reshape(k, d, block, d).transpose(2, 0, 1, 3)       # [r, r + s, :, :]
    flat = jnp.concatenate([q.reshape(block * k, d, d), jnp.zeros((block, d, d), x.dtype)])
    return jnp.sum(flat.reshape(block, k + 1, d, d)[:, :w], axis=0)       # skew: [r, s]


def block_toeplitz(f: jnp.ndarray) -> jnp.ndarray:
    """``(w, d, w, d)`` block Toeplitz matrix with block ``(a, b)`` = ``f[a-b]`` for
    ``a >= b`` and ``f[b-a]^T`` for ``a < b``, from ``f (w, d, d)``: the sequence
    ``v = [f[w-1], ..., f[1], f[0]^T, ..., f[w-1]^T]`` (block ``(a, b)`` is ``v[w-1-a+b]``)
    tiled w times and cut into rows of ``2w - 2`` (a reshape, no gather)."""
    w, d = f.shape[:2]
    v = jnp.concatenate([f[:0:-1], jnp.swapaxes(f, 1, 2)])                  # (2w-1, d, d)
    flat = jnp.broadcast_to(v, (w,) + v.shape).reshape(w * (2 * w - 1), d, d)
    rows = flat[w - 1:w - 1 + w * (2 * w - 2)].reshape(w, 2 * w - 2, d, d)[:, :w]
    return rows.transpose(0, 2, 1, 3)                                         # (a, i, b, j)


def _edge_rows(x: jnp.ndarray, w: int) -> jnp.ndarray:
    """``(w-1, w d)``: row ``j`` holds ``x(a-1-j)`` at offset ``a`` (zero where ``a-1-j < 0``),
    so the product of its transpose with itself is ``sum_{j<b} x(j+a-b) x(j)^T`` in block
    ``(a, b)``, ``a >= b``, for the first ``w - 1`` samples of ``x``."""
    d = x.shape[1]
    padded = jnp.concatenate([jnp.zeros((w - 1, d), x.dtype), x[:w - 1]])   # (2w-2, d)
    return jnp.stack([padded[w - 2 - j:2 * w - 2 - j] for j in range(w - 1)]).reshape(
        w - 1, w * d)


def hankel_gram(x: jnp.ndarray, w: int) -> jnp.ndarray:
    """Gram matrix ``Z^T Z`` (not divided by the count) of the window
    ``Z[t] = [x(t); ...; x(t+w-1)]``, ``t = 0 .. N-w``, of ``x (N, d)``; time-major layout
    (row ``a d + i`` is channel i at offset a): ``(w d, w d)``.

    The block Toeplitz matrix of :func:`lag_products` plus the edge terms as one product:
    ``E_t^T E_t - E_h^T E_h`` with ``E`` = :func:`_edge_rows` of the samples after the
    window's last start (``t``) and of the first ones (``h``).
    """
    n, d = x.shape
    ne = n - w + 1
    e = jnp.concatenate([_edge_rows(x[ne:], w), _edge_rows(x, w)])           # (2w-2, w d)
    sign = jnp.asarray(np.r_[np.ones(w - 1), -np.ones(w - 1)], x.dtype)[:, None]
    return block_toeplitz(lag_products(x, w)).reshape(w * d, w * d) + (e * sign).T @ e
