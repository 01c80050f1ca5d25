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
(docs/findings/table2_shoot_pass.md, "Controls").
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

__all__ = ["MCLog", "mc_init", "mc_work_table", "log_append", "mc_log", "mc_update"]

F32 = jnp.float32
I32 = jnp.int32


@struct.dataclass
class MCLog:
    """Decisions of every env's running trial: s, a, clock (E, L) int32 (clock = primitives
    of the trial before the decision); n (E,) int32 decisions logged (a full log drops
    later decisions); and the update's work table ``sums`` (S * A + 1, 2) float32 of an
    (S, A) Q table, all zeros between updates (:func:`mc_update`)."""

    s: jax.Array
    a: jax.Array
    clock: jax.Array
    n: jax.Array
    sums: jax.Array


def mc_work_table(num_keys: int) -> jax.Array:
    """:func:`mc_update`'s all-zero work table (num_keys + 1, 2) float32 for a Q table of
    ``num_keys`` = S * A entries: each key's count and return sum, and a row for dropped
    entries."""
    return jnp.zeros((num_keys + 1, 2), F32)


def mc_init(num_envs: int, length: int, num_keys: int) -> MCLog:
    """An empty log of ``num_envs`` envs x ``length`` decisions for a Q table of
    ``num_keys`` = S * A entries."""
    z = jnp.zeros((num_envs, length), I32)
    return MCLog(s=z, a=z, clock=z, n=jnp.zeros((num_envs,), I32),
                 sums=mc_work_table(num_keys))


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
    return log.replace(s=s, a=a, clock=clock, n=n)


#: Logged decisions one pass of :func:`mc_update` reads (its loop runs ceil(decisions of the
#: ended trials / this) passes): XLA's scatters and gathers on CPU cost per entry, valid or
#: not, so a pass reads the ended trials' decisions packed, not whole log rows.
MC_PASS_ENTRIES = 256


def mc_update(q: jax.Array, log: MCLog, ended: jax.Array, scored: jax.Array,
              last_clock: jax.Array, learning_rate: Any, discount: Any,
              weight: jax.Array | None = None) -> tuple[jax.Array, MCLog, jax.Array]:
    """Update q (S, A) from the trials that ``ended`` (E,) bool; ``scored`` (E,) bool;
    ``last_clock`` (E,) int32 the primitive index (from 0) of the trial's last primitive;
    ``weight`` (E,) bool: False = the ended trial teaches nothing (e.g. a time-limit
    truncation with ``truncation='skip'``). Returns (q, log emptied where ended, number
    of decisions learned from () float32).

    The learning trials' decisions, packed in env order, are read :data:`MC_PASS_ENTRIES`
    at a time: a first pass sums each (state, action)'s count and returns into the log's
    work table (in packed order), a second gives each decision its key's new value
    (decisions of one key write the same value) and zeroes the key's sums, so a later pass
    that holds the key writes its value again (a zero count moves nothing) and the table
    is all zeros again at the end. The table lives in the log because a fresh table-sized
    zero array per update cost more than the rest of the update
    (docs/findings/learner_cost.md, "The Monte Carlo update")."""
    n_s, n_a = q.shape
    size, length = n_s * n_a, log.s.shape[1]
    if log.sums.shape != (size + 1, 2):
        raise ValueError(f"the log's work table has shape {log.sums.shape}; a {n_s} x {n_a} "
                         f"Q table needs ({size + 1}, 2): mc_init(..., num_keys={size})")
    use = jnp.asarray(ended, bool) if weight is None else jnp.asarray(ended, bool) & weight
    cnt = jnp.where(use, log.n, 0)
    end = jnp.cumsum(cnt)                      # (E,) packed index after each env's decisions
    total = end[-1]
    n_pass = (total + MC_PASS_ENTRIES - 1) // MC_PASS_ENTRIES
    g = jnp.asarray(discount, F32)
    keep = 1.0 - jnp.asarray(learning_rate, F32)

    def entries(p):  # keys (K,) (size: unused) and (count, return) (K, 2) of pass p
        j = p * MC_PASS_ENTRIES + jnp.arange(MC_PASS_ENTRIES, dtype=end.dtype)
        env = jnp.minimum(jnp.sum(end[None, :] <= j[:, None], axis=1), cnt.shape[0] - 1)
        pos = jnp.clip(j - (end[env] - cnt[env]), 0, length - 1)
        valid = j < total
        k = (jnp.asarray(last_clock, I32)[env] - log.clock[env, pos]).astype(F32)
        ret = jnp.where(jnp.asarray(scored, bool)[env], g ** k, 0.0)
        idx = jnp.where(valid, log.s[env, pos] * n_a + log.a[env, pos], size)
        return idx, jnp.stack([valid.astype(F32), jnp.where(valid, ret, 0.0)], -1)

    def add(p, sums):
        idx, w = entries(p)
        return sums.at[idx].add(w, mode="drop")

    def put(p, state):  # a key's first pass writes its new value and zeroes its sums
        flat, sums = state
        idx, _ = entries(p)
        s = sums[idx]
        old = flat.at[idx].get(mode="fill", fill_value=0.0)
        new = old + (1.0 - keep ** s[:, 0]) * (s[:, 1] / jnp.maximum(s[:, 0], 1.0) - old)
        # zeros computed from the values read (s >= 0): XLA then reads before it writes in
        # place, where plain zeros would make it copy the table first
        return flat.at[idx].set(new.astype(F32), mode="drop"), sums.at[idx].set(
            s * 0.0, mode="drop")

    # pass 0 outright, a loop only for more: under vmap a loop with a batched trip count
    # selects its whole carry (the tables) every pass, and most steps need one pass or none
    sums = jax.lax.fori_loop(1, n_pass, add, add(0, log.sums))
    learned = jnp.sum(sums[:size, 0])
    flat, sums = jax.lax.fori_loop(1, n_pass, put, put(0, (q.reshape(-1), sums)))
    q = flat.reshape(n_s, n_a)
    log = log.replace(n=jnp.where(jnp.asarray(ended, bool), 0, log.n).astype(I32), sums=sums)
    return q, log, learned
