"""Run a whole engine :class:`~vbl.engine.Program` inside another program's step or final.

An experiment that trains a baseline per learner (e.g. Figure 9's grid learner on the
final ball of each seed) runs the baseline's program to its end in one traced call:
``init``, ``num_chunks`` x ``step`` in a ``fori_loop``, then its final metrics (the
``final_steps`` of a program with ``begin_final`` in the same loop). Chunk metrics named
in ``totals`` are summed over the training chunks.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["run_program"]


def run_program(prog: Any, cfg: Any, key_init: jax.Array, key_final: jax.Array,
                totals: Callable[[dict], dict] | None = None
                ) -> tuple[dict[str, jax.Array], dict[str, jax.Array]]:
    """``prog`` (a Program) with config ``cfg`` from ``prog.init(key_init, cfg)`` through
    ``prog.num_chunks`` steps to its final metrics (those of ``finish(prog, carry, cfg,
    key_final)``). A program with ``begin_final`` runs its ``final_steps`` in the same loop
    as its training chunks, so its step is compiled once.

    ``totals(metrics) -> {name: float32 ()}`` picks per-chunk amounts to sum over the
    training chunks (None: none). Returns (final metrics, summed totals)."""
    pick = totals or (lambda m: {})
    carry0 = prog.init(key_init, cfg)
    shapes = jax.eval_shape(lambda c: pick(prog.step(c, cfg)[1]), carry0)
    zero = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
    chunks = prog.num_chunks

    def body(i, state):
        carry, acc = state
        if prog.begin_final is not None:
            carry = jax.lax.cond(i == chunks, lambda c: prog.begin_final(c, cfg, key_final),
                                 lambda c: c, carry)
        carry, m = prog.step(carry, cfg)
        return carry, {k: jnp.where(i < chunks, acc[k] + v, acc[k])
                       for k, v in pick(m).items()}

    carry, acc = jax.lax.fori_loop(0, chunks + prog.final_steps, body, (carry0, zero))
    return prog.final(carry, cfg, key_final), acc
