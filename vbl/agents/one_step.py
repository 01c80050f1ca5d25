"""One-step (semi-Markov) Q-learning: the batched update of one table by E transitions.

For the transitions ``(s_i, a_i, r_i, s'_i, n_i)`` of one learner step, all TD errors use
the table Q from before the step::

    target_i = r_i + discount**n_i * (1 - terminal_i) * max_b Q[s'_i, b]
    delta_i  = target_i - Q[s_i, a_i]
    Q[s, a] += lr * mean_{i: (s_i, a_i) = (s, a)} delta_i      (duplicates="mean")
    Q[s, a] += lr * sum_{i: (s_i, a_i) = (s, a)} delta_i       (duplicates="sum")

``n_i`` is the number of primitives of a macro action (1 without macro actions; the macro
reward ``r_i`` is already discounted inside the action). "mean" equals one ordinary
Q-learning update towards the averaged target, so the step size stays ``lr`` however many
environments visit the same pair; "sum" equals applying the single updates one after
another with frozen targets, and can overshoot when ``lr * count > 1``. Transitions with
weight 0 do not count.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from vbl.params import ParamError

__all__ = ["init_q", "q_update", "pair_counts", "transition_arrays"]


def init_q(p: Any) -> jax.Array:
    """A fresh table (S, A) float32 filled with ``p.q_init`` (``p``: QRunnerParams)."""
    return jnp.full((p.num_states, p.num_actions), jnp.asarray(p.q_init, jnp.float32),
                    jnp.float32)


def pair_counts(flat: jax.Array, w: jax.Array, size: int) -> jax.Array:
    """(N,) float32: per transition, the summed weight ``w`` (0/1) of the transitions on its
    table entry ``flat`` (N,) int32, of ``size`` entries. Compares the N entries pairwise
    when N^2 <= size, else scatters into a table-sized buffer; the weights are whole
    numbers, so both sums are exact and equal."""
    if flat.shape[0] ** 2 <= size:
        return jnp.sum(jnp.where(flat[:, None] == flat[None, :], w[None, :], 0.0), axis=1)
    return jnp.zeros(size, jnp.float32).at[flat].add(w)[flat]


def transition_arrays(q, learning_rate, discount, s, a, s_next, weight, num_primitives):
    """The update rules' common inputs as arrays: (q float32, learning rate, per-transition
    discount ``discount ** num_primitives`` (or ``discount``), s, a, s_next int32, weight
    (N,) float32 (1 where ``weight`` is None))."""
    q = q.astype(jnp.float32)
    lr = jnp.asarray(learning_rate, jnp.float32)
    gamma = jnp.asarray(discount, jnp.float32)
    s = jnp.asarray(s, jnp.int32)
    a = jnp.asarray(a, jnp.int32)
    s_next = jnp.asarray(s_next, jnp.int32)
    w = (jnp.ones(s.shape, jnp.float32) if weight is None
         else jnp.asarray(weight).astype(jnp.float32))
    g = gamma if num_primitives is None else gamma ** jnp.asarray(num_primitives, jnp.float32)
    return q, lr, g, s, a, s_next, w


def q_update(q: jax.Array, s: jax.Array, a: jax.Array, r: jax.Array, s_next: jax.Array,
             terminal: jax.Array, learning_rate: Any, discount: Any, *,
             duplicates: str = "mean", weight: jax.Array | None = None,
             num_primitives: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """One synchronous batched Q-learning update of one table (rule in the module doc).

    Args:
      q: (S, A) float32 table.
      s, a, s_next: (N,) int32 state, action, next state of N transitions.
      r: (N,) reward (for a macro action: the discounted sum over its primitives).
      terminal: (N,) bool, no bootstrap.
      learning_rate, discount: scalars (may be traced).
      duplicates: "mean" or "sum" (static), see the module doc.
      weight: (N,) optional 0/1 (or bool) mask; 0 = ignore the transition.
      num_primitives: (N,) optional int, bootstrap with ``discount ** n``.

    Returns:
      (new table (S, A) float32, TD errors (N,) float32 (0 where weight is 0)).
    """
    n_states, n_actions = q.shape
    q, lr, g, s, a, s_next, w = transition_arrays(q, learning_rate, discount, s, a, s_next,
                                                  weight, num_primitives)
    boot = jnp.where(jnp.asarray(terminal, bool), 0.0, g * jnp.max(q[s_next], axis=-1))
    target = jnp.asarray(r, jnp.float32) + boot
    delta = (target - q[s, a]) * w
    flat = s * n_actions + a
    if duplicates == "mean":
        step = delta / jnp.maximum(pair_counts(flat, w, n_states * n_actions), 1.0)
    elif duplicates == "sum":
        step = delta
    else:
        raise ParamError(f"duplicates={duplicates!r}; choose 'mean' or 'sum'")
    new = q.reshape(-1).at[flat].add(lr * step).reshape(n_states, n_actions)
    return new, delta
