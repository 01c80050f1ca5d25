"""Hyper-ellipsoid clusters in a normalised feature space (helpers of Section 2.1).

An ellipsoid is a centre ``c`` (D,) and a shape matrix ``M`` (D, D), symmetric
positive definite; a point ``x`` is inside when ``(x - c)^T M (x - c) <= 1``.
:func:`fit_ellipsoids` turns a k-means clustering of the points into such
ellipsoids: ``M = inv(cov + ridge * I) / r2`` where ``r2`` is the ``coverage``
quantile of the members' squared Mahalanobis distances (so the ellipsoid holds that
fraction of its own members). :func:`kmeans` can restrict clusters to *groups* of
points (e.g. one visibility pattern of the objects): ``k`` clusters per group, a point
only joins a cluster of its own group, so no cluster (and no ellipsoid) mixes groups.
Everything is fixed-shape, jit- and vmap-able.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["mahalanobis2", "mahalanobis2_chunked", "best_inside", "kmeans",
           "fit_ellipsoids"]

F32 = jnp.float32


def mahalanobis2(x: jax.Array, centre: jax.Array, shape: jax.Array) -> jax.Array:
    """Squared distances ``(x - c)^T M (x - c)``: x (..., D), centre (E, D), shape (E, D, D)
    -> (..., E) float32."""
    d = x[..., None, :] - centre
    return jnp.einsum("...ei,eij,...ej->...e", d, shape, d).astype(F32)


def _cholesky_rows(centre: jax.Array, shape: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(L_cat (D, E D), c L (E, D))`` with ``M = L L^T`` per ellipsoid, so that
    ``|x L - c L|^2`` is the squared distance; an all-zero shape (an unused slot) gives
    all-zero factors (distance 0)."""
    e, d = centre.shape
    unused = jnp.all(shape == 0, axis=(1, 2))
    chol = jnp.linalg.cholesky(jnp.where(unused[:, None, None], jnp.eye(d, dtype=F32), shape))
    chol = jnp.where(unused[:, None, None], 0.0, chol).astype(F32)              # (E, D, D)
    return jnp.moveaxis(chol, 0, 1).reshape(d, e * d), jnp.einsum("ei,eij->ej", centre, chol)


def _blocks(flat: jax.Array, chunk: int) -> jax.Array:
    pad = (-flat.shape[0]) % chunk
    return jnp.pad(flat, ((0, pad),) + ((0, 0),) * (flat.ndim - 1)).reshape(
        (-1, chunk) + flat.shape[1:])


def mahalanobis2_chunked(x: jax.Array, centre: jax.Array, shape: jax.Array,
                         chunk: int = 4096) -> jax.Array:
    """:func:`mahalanobis2` for many points, ``chunk`` points at a time, as one matrix
    product per chunk: with ``M = L L^T`` (Cholesky), ``d2 = |x L - c L|^2``, so the
    points meet all E ellipsoids in one (chunk, D) x (D, E D) product (bounded memory: the
    (chunk, E, D) product instead of (P, E, D)). An all-zero shape (an unused slot) gives
    distance 0. x (..., D) -> (..., E)."""
    lead, d = x.shape[:-1], x.shape[-1]
    e = centre.shape[0]
    flat = x.reshape(-1, d)
    n = flat.shape[0]
    lcat, cl = _cholesky_rows(centre, shape)

    def block(b):
        y = (b @ lcat).reshape(-1, e, d) - cl
        return jnp.sum(y * y, axis=-1).astype(F32)

    if n <= chunk:
        return block(flat).reshape(lead + (e,))
    out = jax.lax.map(block, _blocks(flat, chunk))
    return out.reshape(-1, e)[:n].reshape(lead + (e,))


def best_inside(x: jax.Array, group: jax.Array, centre: jax.Array, shape: jax.Array,
                ell_group: jax.Array, ell_ok: jax.Array, base: jax.Array, coef,
                chunk: int = 4096) -> tuple[jax.Array, jax.Array]:
    """For each point, the containing ellipsoid of lowest ``base[e] + coef * d2`` among the
    usable ones (``ell_ok``) of the point's group, without materialising the (P, E)
    distances (memory O(chunk E)).

    x (..., D), group (...) int32; centre (E, D), shape (E, D, D), ell_group (E,) int32,
    ell_ok (E,) bool, base (E,) float32, coef scalar. Returns (index (...) int32, any
    (...) bool: some ellipsoid contains the point)."""
    lead, d = x.shape[:-1], x.shape[-1]
    e = centre.shape[0]
    flat, gflat = x.reshape(-1, d), group.reshape(-1)
    n = flat.shape[0]
    lcat, cl = _cholesky_rows(centre, shape)
    base = jnp.asarray(base, F32)

    def block(args):
        b, g = args
        y = (b @ lcat).reshape(-1, e, d) - cl
        d2 = jnp.sum(y * y, axis=-1)
        inside = (d2 <= 1.0) & ell_ok & (g[:, None] == ell_group)
        score = jnp.where(inside, base + coef * d2, jnp.inf)
        return jnp.argmin(score, axis=-1).astype(jnp.int32), jnp.any(inside, axis=-1)

    if n <= chunk:
        idx, hit = block((flat, gflat))
    else:
        idx, hit = jax.lax.map(block, (_blocks(flat, chunk), _blocks(gflat, chunk)))
        idx, hit = idx.reshape(-1)[:n], hit.reshape(-1)[:n]
    return idx.reshape(lead), hit.reshape(lead)


def kmeans(key: jax.Array, pts: jax.Array, mask: jax.Array, k: int, iters: int,
           group: jax.Array | None = None, num_groups: int = 1
           ) -> tuple[jax.Array, jax.Array]:
    """Lloyd's k-means on the masked points, ``k`` clusters per group.

    Args:
      key: PRNG key (the initial centres of a group are ``k`` of its masked points drawn
        with replacement; a group without masked points keeps empty clusters).
      pts: (P, D) float32; mask: (P,) bool, points that take part.
      k, iters: clusters per group and Lloyd iterations (static).
      group: (P,) int32 in [0, num_groups) or None (one group); cluster ``j`` belongs to
        group ``j // k`` and a point is only assigned to clusters of its group.
      num_groups: number of groups (static).
    Returns: (centres (num_groups * k, D) float32, assignment (P,) int32 in
    [0, num_groups * k)).
    """
    n_cl = k * num_groups
    group = jnp.zeros(pts.shape[:1], jnp.int32) if group is None else group.astype(jnp.int32)
    cl_group = jnp.repeat(jnp.arange(num_groups, dtype=jnp.int32), k)           # (K,)

    def init(kg, g):
        m = mask & (group == g)
        logits = jnp.where(m, 0.0, -jnp.inf)
        logits = jnp.where(jnp.any(m), logits, 0.0).astype(F32)
        return jax.random.categorical(kg, logits, shape=(k,))

    idx = jax.vmap(init)(jax.random.split(key, num_groups),
                         jnp.arange(num_groups, dtype=jnp.int32)).reshape(-1)
    centres = pts[idx]
    w = mask.astype(F32)
    wrong = group[:, None] != cl_group[None, :]                                  # (P, K)

    def assign(c):
        d = jnp.sum((pts[:, None, :] - c[None]) ** 2, axis=-1)                 # (P, K)
        return jnp.argmin(jnp.where(wrong, jnp.inf, d), axis=-1).astype(jnp.int32)

    def lloyd(_, c):
        a = assign(c)
        one = jax.nn.one_hot(a, n_cl, dtype=F32) * w[:, None]
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
    n, d = pts.shape
    one = jax.nn.one_hot(assign, k, dtype=F32) * mask.astype(F32)[:, None]      # (P, k)
    cnt = jnp.sum(one, axis=0)
    mean = (one.T @ pts) / jnp.maximum(cnt, 1.0)[:, None]
    dev = pts - mean[assign]                                                     # (P, D)
    outer = (dev[:, :, None] * dev[:, None, :]).reshape(n, d * d)
    cov = (one.T @ outer).reshape(k, d, d) / jnp.maximum(cnt, 1.0)[:, None, None]
    cov = cov + jnp.asarray(ridge, F32) * jnp.eye(d, dtype=F32)
    prec = jnp.linalg.inv(cov)
    own = jnp.einsum("pi,pij,pj->p", dev, prec[assign], dev)                     # (P,)
    member = one > 0
    srt = jnp.sort(jnp.where(member, own[:, None], jnp.inf).T, axis=-1)         # (k, P)
    q = jnp.ceil(jnp.asarray(coverage, F32) * cnt).astype(jnp.int32) - 1
    q = jnp.clip(q, 0, n - 1)
    r2 = jnp.take_along_axis(srt, q[:, None], axis=-1)[:, 0]
    r2 = jnp.where(jnp.isfinite(r2), jnp.maximum(r2, 1e-6), 1.0)
    shape = prec / r2[:, None, None]
    return mean.astype(F32), shape.astype(F32), cnt
