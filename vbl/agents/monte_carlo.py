"""Every-visit Monte Carlo updates of a Q-table from whole trials (E parallel envs).

Each env logs its running trial's decisions (discrete state, action, primitive index of
the decision). When the trial ends, every logged decision gets the return
``discount**k`` if the trial scored, k = primitives from the decision to the scoring
primitive (0: the decision's own primitive scored), else 0; the Q entry of a (state,
action) with c such decisions in this batch moves towards their mean return by
``1 - (1 - lr)**c`` (c updates towards the same mean), and the log empties. No
bootstrapping: a state that aliases situations needing different actions does not
spread a wrong value to its predecessors. On the on-line learner's boxes Monte Carlo
values beat one-step Q-learning by far (docs/findings/fig9_incremental.md,
"Deviations and the evidence for them"); on Table 2's task too
(docs/findings/table2_shoot_pass.md, "Why shooting is not reproduced").
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

__all__ = ["MCLog", "mc_init", "log_append", "mc_log", "mc_update"]

F32 = jnp.float32
I32 = jnp.int32


@struct.dataclass
class MCLog:
    """Decisions of every env's running trial: s, a, clock (E, L) int32 (clock = primitives
    of the trial before the decision); n (E,) int32 decisions logged. A full log drops
    later decisions."""

    s: jax.Array
    a: jax.Array
    clock: jax.Array
    n: jax.Array


def mc_init(num_envs: int, length: int) -> MCLog:
    z = jnp.zeros((num_envs, length), I32)
    return MCLog(s=z, a=z, clock=z, n=jnp.zeros((num_envs,), I32))


def log_append(fields: tuple, n: jax.Array, decided: jax.Array,
               values: tuple) -> tuple[tuple, jax.Array]:
    """Append one entry per env to per-env logs: ``fields`` (E, L, ...) arrays, ``n`` (E,)
    int32 entries so far, ``values`` (E, ...) one per field (cast to the field's dtype),
    written where ``decided`` (E,) bool and the log has room (a full log drops the entry).
    Returns (fields, n)."""
    length = fields[0].shape[1]
    rows = jnp.arange(fields[0].shape[0])
    i = jnp.minimum(n, length - 1)
    w = jnp.asarray(decided, bool) & (n < length)

    def put(arr, v):
        v = jnp.asarray(v, arr.dtype)
        keep = w.reshape(w.shape + (1,) * (arr.ndim - 2))
        return arr.at[rows, i].set(jnp.where(keep, v, arr[rows, i]))

    return tuple(put(f, v) for f, v in zip(fields, values, strict=True)), n + w.astype(I32)


def mc_log(log: MCLog, decided: jax.Array, s: jax.Array, a: jax.Array,
           clock: jax.Array) -> MCLog:
    """Append (s, a, clock) (E,) where ``decided`` (E,) bool."""
    (s, a, clock), n = log_append((log.s, log.a, log.clock), log.n, decided, (s, a, clock))
    return MCLog(s=s, a=a, clock=clock, n=n)


#: Ended envs whose logs one pass of :func:`mc_update` reads (its loop runs ceil(ended /
#: this) passes): XLA's scatters on CPU cost per entry, so reading only the ended envs'
#: rows, not all E x L entries, is what makes the update cheap.
MC_BLOCK_ENVS = 8


def mc_update(q: jax.Array, log: MCLog, ended: jax.Array, scored: jax.Array,
              last_clock: jax.Array, learning_rate: Any, discount: Any,
              weight: jax.Array | None = None) -> tuple[jax.Array, MCLog, jax.Array]:
    """Update q (S, A) from the trials that ``ended`` (E,) bool; ``scored`` (E,) bool;
    ``last_clock`` (E,) int32 the primitive index (from 0) of the trial's last primitive;
    ``weight`` (E,) bool: False = the ended trial teaches nothing (e.g. a time-limit
    truncation with ``truncation='skip'``). Returns (q, log emptied where ended, number
    of decisions learned from () float32).

    The ended envs' rows are read in blocks of :data:`MC_BLOCK_ENVS`: a first pass sums
    each (state, action)'s count and returns into table-sized sums, a second gives each
    logged decision its key's new value (decisions of one key write the same value)."""
    n_s, n_a = q.shape
    size, (n_env, length) = n_s * n_a, log.s.shape
    use = jnp.asarray(ended, bool) if weight is None else jnp.asarray(ended, bool) & weight
    block = min(MC_BLOCK_ENVS, n_env)
    order = jnp.argsort(~use, stable=True)  # the learning envs first
    n_blocks = (jnp.sum(use, dtype=jnp.int32) + block - 1) // block
    order = jnp.concatenate([order, jnp.full((block,), n_env, order.dtype)])  # pad rows
    g = jnp.asarray(discount, F32)

    def entries(b):  # keys (block * L,) (size: unused) and returns of block b's rows
        rows = jax.lax.dynamic_slice(order, (b * block,), (block,))
        ok = rows < n_env
        r = jnp.minimum(rows, n_env - 1)
        valid = (jnp.arange(length)[None] < log.n[r][:, None]) & (ok & use[r])[:, None]
        k = (jnp.asarray(last_clock, I32)[r][:, None] - log.clock[r]).astype(F32)
        ret = jnp.where(jnp.asarray(scored, bool)[r][:, None], g ** k, 0.0)
        idx = jnp.where(valid, log.s[r] * n_a + log.a[r], size).reshape(-1)
        return idx, jnp.stack([valid.reshape(-1).astype(F32),
                               jnp.where(valid, ret, 0.0).reshape(-1)], -1)

    def add(b, sums):
        idx, w = entries(b)
        return sums.at[idx].add(w, mode="drop")

    sums = jax.lax.fori_loop(0, n_blocks, add, jnp.zeros((size + 1, 2), F32))
    keep = 1.0 - jnp.asarray(learning_rate, F32)

    before = q.reshape(-1)

    def put(b, flat):  # every block reads the table from before the update
        idx, _ = entries(b)
        s = sums[idx]
        old = before.at[idx].get(mode="fill", fill_value=0.0)
        new = old + (1.0 - keep ** s[:, 0]) * (s[:, 1] / jnp.maximum(s[:, 0], 1.0) - old)
        return flat.at[idx].set(new.astype(F32), mode="drop")

    q = jax.lax.fori_loop(0, n_blocks, put, before).reshape(n_s, n_a)
    log = log.replace(n=jnp.where(jnp.asarray(ended, bool), 0, log.n).astype(I32))
    return q, log, jnp.sum(sums[:size, 0])
