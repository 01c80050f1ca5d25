"""First-episode evaluation: run a policy step until every env finished one episode.

:func:`first_episodes` is the one greedy / near-greedy evaluation loop of the tabular
learners: a ``lax.while_loop`` over a batch of E envs that records, per env, the outcome
and length of its first finished episode and stops as soon as every env has one (later
steps could not change the result) or after ``num_steps`` steps.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["first_episodes"]


def first_episodes(step: Callable, carry: Any, num_envs: int,
                   num_steps: int) -> dict[str, jax.Array]:
    """Evaluate ``step(carry) -> (carry, done, success, length)`` (each (E,): the episode
    ended at this step, it scored, its length so far incl. this step) from ``carry``.

    Returns scalars: ``success_rate`` (fraction of the E envs whose first episode scored;
    an env that finished none counts as a failure), ``finished`` (fraction that finished
    one) and ``mean_primitives`` (mean length of the finished first episodes, 0 if none).
    """
    first = dict(finished=jnp.zeros((num_envs,), bool), success=jnp.zeros((num_envs,), bool),
                 primitives=jnp.zeros((num_envs,), jnp.int32))

    def body(state):
        i, c, f = state
        c, done, success, length = step(c)
        new_first = done & ~f["finished"]
        f = dict(finished=f["finished"] | done,
                 success=jnp.where(new_first, success, f["success"]),
                 primitives=jnp.where(new_first, length, f["primitives"]))
        return i + 1, c, f

    def cond(state):
        i, _, f = state
        return (i < num_steps) & ~jnp.all(f["finished"])

    _, _, f = jax.lax.while_loop(cond, body, (jnp.int32(0), carry, first))
    fin = f["finished"].astype(jnp.float32)
    n_fin = jnp.sum(fin)
    return dict(success_rate=jnp.sum(f["success"].astype(jnp.float32)) / num_envs,
                finished=n_fin / num_envs,
                mean_primitives=jnp.sum(f["primitives"] * fin) / jnp.maximum(n_fin, 1.0))
