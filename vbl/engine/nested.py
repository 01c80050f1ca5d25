"""Run a whole engine :class:`~vbl.engine.Program` inside another program's step or final.

An experiment that trains a baseline per learner (e.g. Figure 9's grid learner on the
final ball of each seed) runs the baseline's program to its end in one traced call:
``init``, ``num_chunks`` x ``step`` in a ``fori_loop``, ``final``. Chunk metrics named in
``totals`` are summed over the chunks.
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
    ``prog.num_chunks`` steps to ``prog.final(carry, cfg, key_final)``.

    ``totals(metrics) -> {name: float32 ()}`` picks per-chunk amounts to sum (None: none).
    Returns (final metrics, summed totals)."""
    pick = totals or (lambda m: {})
    carry0 = prog.init(key_init, cfg)
    shapes = jax.eval_shape(lambda c: pick(prog.step(c, cfg)[1]), carry0)
    zero = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    def body(_, state):
        carry, acc = state
        carry, m = prog.step(carry, cfg)
        return carry, {k: acc[k] + v for k, v in pick(m).items()}

    carry, acc = jax.lax.fori_loop(0, prog.num_chunks, body, (carry0, zero))
    return prog.final(carry, cfg, key_final), acc
