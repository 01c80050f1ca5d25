"""Linear algebra that is safe to batch on CPU.

jaxlib's CPU SVD kernel (LAPACK ``gesdd`` through XLA's FFI) parallelises a batched call
over XLA's intra-op thread pool and blocks its own pool thread until the pieces finish.
When two such calls run at once (independent ops of one program, or two devices of a
sharded one) on a small pool (2 threads on a 2-core machine), every pool thread can end
up blocked waiting for pieces that no free thread will run: the program hangs with all
threads in a futex wait (seen in Table 2's identification of three objects at once, and
reproduced by ``tests/test_jax_deadlock_regression.py``). :func:`svd_thin` batches as a
``lax.map`` instead, so every kernel call has batch 1 and never waits on the pool.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["svd_thin", "eigh_desc", "x64_scope"]


def x64_scope():
    """Context manager: 64-bit types on (``jax.enable_x64(True)``) for the code inside it.

    Every public function of :mod:`vbl.sysid` runs inside it, so identification computes in
    the dtype its params ask for (float64 by default) and gives the same numbers whether or
    not ``jax_enable_x64`` is on globally. Outside the scope the global setting applies again:
    a float64 array returned from inside stays float64, but new arrays follow the global flag.
    """
    return jax.enable_x64(True)


@jax.custom_batching.custom_vmap
def svd_thin(x: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Thin SVD ``x = u diag(s) vh`` of one (M, N) matrix: u (M, K), s (K,), vh (K, N),
    K = min(M, N); ``vmap`` runs it matrix by matrix (see the module docstring)."""
    u, s, vh = jnp.linalg.svd(x, full_matrices=False)
    return u, s, vh


@svd_thin.def_vmap
def _svd_thin_vmap(axis_size, in_batched, x):
    (batched,) = in_batched
    if not batched:
        return tuple(svd_thin(x)), (False, False, False)
    return tuple(jax.lax.map(svd_thin, x)), (True, True, True)


@jax.custom_batching.custom_vmap
def eigh_desc(s: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Eigenvalues (descending) and eigenvectors (columns) of one symmetric matrix; ``vmap``
    runs it matrix by matrix, as :func:`svd_thin` (the same kernel-pool hazard applies to
    any batched LAPACK call that splits its batch over the pool)."""
    w, v = jnp.linalg.eigh(s)
    return w[::-1], v[:, ::-1]


@eigh_desc.def_vmap
def _eigh_desc_vmap(axis_size, in_batched, s):
    (batched,) = in_batched
    if not batched:
        return tuple(eigh_desc(s)), (False, False)
    return tuple(jax.lax.map(eigh_desc, s)), (True, True)
