"""Multi-step returns for the batched tabular learner: eligibility traces over a window.

Under state aliasing one-step Q-learning averages away the action gap and its greedy
policy cycles between look-alike states; multi-step returns are the standard remedy. Each
of a learner's E environments keeps a shift register of its last L (state, action,
eligibility) pairs (``TraceParams.length``, static), and every learner step applies each
environment's TD error to all L pairs in one batched scatter into the table. The rule
(``agent.update``: ``"peng"``, ``"naive"``, ``"watkins"`` or ``"sarsa"``) is static, lambda
is traced; with lambda = 0 peng, naive and watkins equal the one-step update exactly. The
duplicate rule (``QRunnerParams.duplicates``: ``"mean"`` or ``"sum"``) weighs the
contributions on one (s, a) by their eligibilities.

See docs/agents.md, "Multi-step returns" (eligibilities, TD errors, the duplicate rule).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.agents.one_step import transition_arrays
from vbl.params import ParamError, param

__all__ = ["TRACE_KINDS", "TraceParams", "TraceState", "trace_init", "trace_update"]

#: TD-error / cut rule of the trace (static choice), see the module doc.
TRACE_KINDS = ("peng", "naive", "watkins", "sarsa")
#: Envs per block of the table scatter: only blocks holding envs whose transition updates
#: (asynchronous macro actions: about 1 in 6.6) are scattered (:func:`_scatter_active`).
_BLOCK = 16


@struct.dataclass
class TraceParams:
    """Eligibility traces truncated to the last ``length`` actions of each environment (the
    trace rules of ``update``: peng, naive, watkins, sarsa)."""

    lam: float = param(0.0, doc="trace decay lambda per action (0: one-step; 1: returns "
                       "over the whole window)", ge=0.0, le=1.0)
    length: int = param(16, doc="window L: (state, action) pairs kept per environment",
                        unit="actions", static=True, ge=1)


@struct.dataclass
class TraceState:
    """Per-environment trace window of one learner (leading axis E; slot 0 = newest)."""

    s: jax.Array       #: (E, L) int32 states of the buffered pairs
    a: jax.Array       #: (E, L) int32 actions
    e: jax.Array       #: (E, L) float32 eligibility for the next transition (0: empty)
    a_next: jax.Array  #: (E,) int32 Sarsa: the action already chosen for the next step (-1: none)


def trace_init(num_envs: int, length: int) -> TraceState:
    """An empty window (E, L)."""
    if int(length) < 1:
        raise ParamError(f"trace length={length!r} must be >= 1")
    shape = (int(num_envs), int(length))
    return TraceState(s=jnp.zeros(shape, jnp.int32), a=jnp.zeros(shape, jnp.int32),
                      e=jnp.zeros(shape, jnp.float32),
                      a_next=jnp.full((int(num_envs),), -1, jnp.int32))


def _check_lambda(lam: Any) -> None:
    try:
        arr = np.asarray(lam, float)
    except (TypeError, jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        return  # traced: checked where the params were validated
    if np.any((arr < 0) | (arr > 1)) or np.any(np.isnan(arr)):
        raise ParamError(f"trace lambda={lam!r} must be in [0, 1]")


def _scatter_active(q_flat: jax.Array, flat: jax.Array, d: jax.Array, w: jax.Array,
                    active: jax.Array, lr: jax.Array, mean: bool) -> jax.Array:
    """``q_flat`` (S * A,) plus ``lr`` times the contributions ``d`` (E, L) at ``flat`` (E, L)
    (divided by ``max(sum of w on the entry, 1)`` if ``mean``) of the ``active`` (E,) envs.

    An inactive env's contributions are exact zeros (finite TD errors), so only the active
    ones are scattered: their rows, in env order, in blocks of ``_BLOCK`` envs (a loop over
    as many blocks as there are active envs; rows past the last active env add 0). Same
    additions in the same order as one scatter of all E x L contributions, hence the same
    table bit for bit.
    """
    n_envs = flat.shape[0]
    n_blocks = -(-n_envs // _BLOCK)
    rows = jnp.nonzero(active, size=n_blocks * _BLOCK, fill_value=0)[0]
    n_active = jnp.sum(active, dtype=jnp.int32)
    used = (n_active + _BLOCK - 1) // _BLOCK

    def scatter(acc, values):
        """acc + the active rows of ``values(rows (B,)) -> (B, L)`` at their entries."""
        def body(c):
            b, acc = c
            r = jax.lax.dynamic_slice(rows, (b * _BLOCK,), (_BLOCK,))
            live = (b * _BLOCK + jnp.arange(_BLOCK)) < n_active
            v = jnp.where(live[:, None], values(r), 0.0)
            return b + 1, acc.at[flat[r].reshape(-1)].add(v.reshape(-1))

        return jax.lax.while_loop(lambda c: c[0] < used, body, (jnp.int32(0), acc))[1]

    if not mean:
        return scatter(q_flat, lambda r: lr * d[r])
    tot = scatter(jnp.zeros_like(q_flat), lambda r: w[r])
    return scatter(q_flat, lambda r: lr * (d[r] / jnp.maximum(tot[flat[r]], 1.0)))


def trace_update(q: jax.Array, tr: TraceState, s: jax.Array, a: jax.Array, r: jax.Array,
                 s_boot: jax.Array, terminal: jax.Array, done: jax.Array, learning_rate: Any,
                 discount: Any, lam: Any, *, kind: str = "peng", duplicates: str = "mean",
                 weight: jax.Array | None = None, num_primitives: jax.Array | None = None,
                 a_boot: jax.Array | None = None, advance: jax.Array | None = None
                 ) -> tuple[jax.Array, jax.Array, TraceState]:
    """One synchronous trace update of one table by the E transitions of a learner step.

    Args:
      q: (S, A) float32 table (targets and TD errors use it as given).
      tr: the window before this step (eligibilities already decayed for this transition).
      s, a: (E,) int32 state and action of this step's transitions (pushed into slot 0).
      r: (E,) reward (macro action: discounted sum over its primitives).
      s_boot: (E,) int32 state to bootstrap from; terminal: (E,) bool, no bootstrap.
      done: (E,) bool, the episode ended (the window is cleared after the update).
      learning_rate, discount, lam: scalars (may be traced).
      kind, duplicates: static rules (module doc).
      weight: (E,) optional 0/1 mask (0: the transition updates nothing).
      num_primitives: (E,) optional int, the action's discount is ``discount ** n``.
      a_boot: (E,) int32, Sarsa only: the action taken next in ``s_boot``.
      advance: (E,) optional bool; False: the env's action runs on (asynchronous macro
        actions), so it pushes nothing, updates nothing and keeps its window as it is.

    Returns (new table, TD errors of the current pairs (E,) float32 (0 where weight is 0),
    the window for the next step: decayed by ``discount**n * lam``, cleared where ``done``).
    """
    if kind not in TRACE_KINDS:
        raise ParamError(f"trace kind={kind!r}; choose one of {list(TRACE_KINDS)}")
    if duplicates not in ("mean", "sum"):
        raise ParamError(f"duplicates={duplicates!r}; choose 'mean' or 'sum'")
    if kind == "sarsa" and a_boot is None:
        raise ParamError("trace kind 'sarsa' needs a_boot (the next action)")
    _check_lambda(lam)
    n_states, n_actions = q.shape
    q, lr, g, s, a, s_boot, mask = transition_arrays(q, learning_rate, discount, s, a, s_boot,
                                                     weight, num_primitives)
    if advance is not None:
        mask = mask * jnp.asarray(advance).astype(jnp.float32)
    v_s = jnp.max(q[s], axis=-1)
    q_sa = q[s, a]
    if kind == "sarsa":
        b = q[s_boot, jnp.asarray(a_boot, jnp.int32)]
    else:
        b = jnp.max(q[s_boot], axis=-1)
    boot = jnp.where(jnp.asarray(terminal, bool), 0.0, g * b)
    target = jnp.asarray(r, jnp.float32) + boot
    delta = (target - q_sa) * mask
    delta_old = (target - v_s) * mask if kind == "peng" else delta
    old_e = tr.e[:, :-1]
    if kind == "watkins":  # a non-greedy action ends the older pairs' returns
        old_e = jnp.where((q_sa >= v_s)[:, None], old_e, 0.0)
    ones = jnp.ones(s.shape + (1,), jnp.float32)
    ss = jnp.concatenate([s[:, None], tr.s[:, :-1]], axis=1)
    aa = jnp.concatenate([a[:, None], tr.a[:, :-1]], axis=1)
    ee = jnp.concatenate([ones, old_e], axis=1)
    d = jnp.concatenate([delta[:, None],
                         jnp.broadcast_to(delta_old[:, None], old_e.shape)], axis=1) * ee
    w = ee * mask[:, None]
    new = _scatter_active(q.reshape(-1), ss * n_actions + aa, d, w, mask > 0, lr,
                          duplicates == "mean").reshape(n_states, n_actions)
    decay = (g * jnp.asarray(lam, jnp.float32))[..., None] * jnp.ones_like(ee)
    e_next = jnp.where(jnp.asarray(done, bool)[:, None], 0.0, ee * decay)
    if advance is not None:  # envs whose action runs on keep their window
        keep = ~jnp.asarray(advance, bool)[:, None]
        ss, aa = jnp.where(keep, tr.s, ss), jnp.where(keep, tr.a, aa)
        e_next = jnp.where(keep, tr.e, e_next)
    return new, delta, tr.replace(s=ss, a=aa, e=e_next.astype(jnp.float32))
