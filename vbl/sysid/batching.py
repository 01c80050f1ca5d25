"""Many data sets through one jitted, vmapped identification, in chunks.

A vmap over thousands of data sets makes every intermediate array thousands of matrices
long, and its working set leaves the cache: the cost per identification grows with the batch.
:func:`in_chunks` runs fixed-size chunks in sequence instead (the last one padded to a power
of two), so the cost per identification stays that of one chunk and at most
``log2(chunk) + 1`` batch shapes compile whatever the number of data sets.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["chunk_sizes", "in_chunks"]


def chunk_sizes(b: int, chunk: int) -> list[tuple[int, int]]:
    """``(data sets, compiled batch)`` per call: full chunks of ``chunk``, then the rest
    padded to the next power of two (so at most ``log2(chunk) + 1`` batch shapes compile)."""
    out = [(chunk, chunk)] * (b // chunk)
    rest = b % chunk
    if rest:
        out.append((rest, min(chunk, 1 << (rest - 1).bit_length())))
    return out


def in_chunks(fn: Callable[[Any, Any], Any], u, y, chunk: int):
    """``fn(u, y)`` (batched over the leading axis of ``u (B, ...)``, ``y (B, ...)``,
    returning a pytree of ``(B, ...)`` arrays) in chunks of ``chunk`` data sets, the last
    chunk padded with copies of its first data set and the padding dropped; the chunks'
    results concatenated in order."""
    parts, start = [], 0
    for count, size in chunk_sizes(u.shape[0], chunk):
        sl = slice(start, start + count)
        uc, yc = (u, y) if count == u.shape[0] else (u[sl], y[sl])
        if size > count:
            reps = np.r_[np.arange(count), np.zeros(size - count, int)]
            uc, yc = uc[reps], yc[reps]
        out = fn(uc, yc)
        if size > count:
            out = jax.tree_util.tree_map(lambda a, c=count: a[:c], out)
        parts.append(out)
        start += count
    if len(parts) == 1:
        return parts[0]
    return jax.tree_util.tree_map(lambda *a: jnp.concatenate(a), *parts)
