"""Hyper-ellipsoid clusters in a normalised feature space (helpers of Section 2.1).

An ellipsoid is a centre ``c`` (D,) and a shape matrix ``M`` (D, D), symmetric
positive definite; a point ``x`` is inside when ``(x - c)^T M (x - c) <= 1``.
:func:`fit_ellipsoids` turns a weighted k-means clustering of the points into such
ellipsoids: ``M = inv(cov + ridge * I) / r2`` where ``r2`` is the ``coverage``
quantile of the members' squared Mahalanobis distances (so the ellipsoid holds that
fraction of its own members). Everything is fixed-shape, jit- and vmap-able.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["mahalanobis2", "mahalanobis2_chunked", "kmeans", "fit_ellipsoids"]

F32 = jnp.float32


def mahalanobis2(x: jax.Array, centre: jax.Array, shape: jax.Array) -> jax.Array:
    """Squared distances ``(x - c)^T M (x - c)``: x (..., D), centre (E, D), shape (E, D, D)
    -> (..., E) float32."""
    d = x[..., None, :] - centre
    return jnp.einsum("...ei,eij,...ej->...e", d, shape, d).astype(F32)


def mahalanobis2_chunked(x: jax.Array, centre: jax.Array, shape: jax.Array,
                         chunk: int = 4096) -> jax.Array:
    """:func:`mahalanobis2` for many points, ``chunk`` points at a time (bounded memory:
    the (chunk, E, D) difference array instead of (P, E, D)). x (..., D) -> (..., E)."""
    lead, d = x.shape[:-1], x.shape[-1]
    flat = x.reshape(-1, d)
    n = flat.shape[0]
    if n <= chunk:
        return mahalanobis2(x, centre, shape)
    pad = (-n) % chunk
    blocks = jnp.pad(flat, ((0, pad), (0, 0))).reshape(-1, chunk, d)
    out = jax.lax.map(lambda b: mahalanobis2(b, centre, shape), blocks)
    return out.reshape(-1, centre.shape[0])[:n].reshape(lead + (centre.shape[0],))


def kmeans(key: jax.Array, pts: jax.Array, mask: jax.Array, k: int, iters: int
           ) -> tuple[jax.Array, jax.Array]:
    """Lloyd's k-means on the masked points.

    Args:
      key: PRNG key (initial centres are ``k`` masked points drawn with replacement).
      pts: (P, D) float32; mask: (P,) bool, points that take part.
      k, iters: number of centres and of Lloyd iterations (static).
    Returns: (centres (k, D) float32, assignment (P,) int32 in [0, k)).
    """
    logits = jnp.where(mask, 0.0, -jnp.inf)
    logits = jnp.where(jnp.any(mask), logits, 0.0).astype(F32)
    idx = jax.random.categorical(key, logits, shape=(k,))
    centres = pts[idx]
    w = mask.astype(F32)

    def assign(c):
        d = jnp.sum((pts[:, None, :] - c[None]) ** 2, axis=-1)
        return jnp.argmin(d, axis=-1).astype(jnp.int32)

    def lloyd(_, c):
        a = assign(c)
        one = jax.nn.one_hot(a, k, dtype=F32) * w[:, None]
        cnt = jnp.sum(one, axis=0)
        new = (one.T @ pts) / jnp.maximum(cnt, 1.0)[:, None]
        return jnp.where(cnt[:, None] > 0, new, c)

    centres = jax.lax.fori_loop(0, iters, lloyd, centres)
    return centres, assign(centres)


def fit_ellipsoids(pts: jax.Array, mask: jax.Array, assign: jax.Array, k: int,
                   coverage: jax.Array, ridge: jax.Array
                   ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """One ellipsoid per cluster of the masked points.

    Args:
      pts (P, D) float32; mask (P,) bool; assign (P,) int32 cluster of each point.
      k: number of clusters (static); coverage: fraction of members inside (0, 1];
      ridge: added to the covariance diagonal (normalised units^2, > 0).
    Returns: (centre (k, D), shape (k, D, D), count (k,) float32 members).
    """
    d = pts.shape[-1]
    one = jax.nn.one_hot(assign, k, dtype=F32) * mask.astype(F32)[:, None]      # (P, k)
    cnt = jnp.sum(one, axis=0)
    mean = (one.T @ pts) / jnp.maximum(cnt, 1.0)[:, None]
    dev = pts[:, None, :] - mean[None]                                           # (P, k, D)
    cov = jnp.einsum("pk,pki,pkj->kij", one, dev, dev) / jnp.maximum(cnt, 1.0)[:, None, None]
    cov = cov + jnp.asarray(ridge, F32) * jnp.eye(d, dtype=F32)
    prec = jnp.linalg.inv(cov)
    own = jnp.einsum("pki,kij,pkj->pk", dev, prec, dev)                          # (P, k)
    member = one > 0
    srt = jnp.sort(jnp.where(member, own, jnp.inf).T, axis=-1)                  # (k, P)
    q = jnp.ceil(jnp.asarray(coverage, F32) * cnt).astype(jnp.int32) - 1
    q = jnp.clip(q, 0, pts.shape[0] - 1)
    r2 = jnp.take_along_axis(srt, q[:, None], axis=-1)[:, 0]
    r2 = jnp.where(jnp.isfinite(r2), jnp.maximum(r2, 1e-6), 1.0)
    shape = prec / r2[:, None, None]
    return mean.astype(F32), shape.astype(F32), cnt
