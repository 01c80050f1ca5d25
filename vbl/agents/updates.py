"""The tabular update rules behind one interface: ``UpdateRule(init, update, act)``.

A rule turns one learner step's E transitions (:class:`Transition`) into a new (S, A)
table. :func:`make_rule` is the one place that chooses it, by name (:data:`RULES`):

* ``"q_learning"``: one-step (semi-Markov) Q-learning, :mod:`vbl.agents.one_step`;
* ``"peng"``, ``"naive"``, ``"watkins"``, ``"sarsa"``: eligibility traces over each env's
  last ``trace.length`` decisions, :mod:`vbl.agents.traces`;
* ``"monte_carlo"``: every decision of a trial moves towards ``discount**k`` (k primitives
  to the goal) when the trial ends, :mod:`vbl.agents.monte_carlo`.

Every rule works with macro actions of either mode. A transition is one decision: with
asynchronous macro actions an env's transition arrives at the primitive its action ends
(``Transition.advance``), carries the discounted reward of its n primitives and
bootstraps with ``discount**n``; traces decay by ``discount**n * lambda`` per decision.

``init(num_envs, num_keys) -> state`` (a pytree: per-env parts with leading axis E;
``num_keys`` = S * A, the table's size); ``update(q, state, t, hp) ->
(q, state, td_abs)`` with ``hp`` the agent's params (``learning_rate``, ``discount``,
``trace.lam``; traced) and ``td_abs`` the mean |TD error| of the updated transitions
(0 for Monte Carlo); ``act(state, chosen) -> action`` overrides the policy's choice
(Sarsa acts with the next action it bootstrapped from; identity otherwise).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from vbl.agents.monte_carlo import mc_init, mc_log, mc_update
from vbl.agents.one_step import q_update
from vbl.agents.traces import TRACE_KINDS, trace_init, trace_update
from vbl.params import ParamError

__all__ = ["RULES", "Transition", "UpdateRule", "make_rule"]

#: Update rules (static choice): one-step Q-learning, the trace kinds, Monte Carlo.
RULES = ("q_learning", *TRACE_KINDS, "monte_carlo")


@struct.dataclass
class Transition:
    """One learner step's transitions of E envs, each (E,) (``None``: all True)."""

    s: jax.Array          #: int32 state where the action started
    a: jax.Array          #: int32 action
    r: jax.Array          #: float32 reward, discounted sum over the action's primitives
    n: jax.Array          #: int32 primitives of the action
    s_boot: jax.Array     #: int32 state to bootstrap from
    terminal: jax.Array   #: bool, no bootstrap (after the truncation rule)
    done: jax.Array       #: bool, the episode ended at this step
    truncated: jax.Array  #: bool, ended by the time limit only
    weight: Any           #: bool or None: False = the transition teaches nothing
    advance: Any          #: bool or None: the env's action ended here (async macro actions)
    decided: jax.Array    #: bool, the env chose its action at this step
    clock: jax.Array      #: int32 primitives of the trial before this step
    last_clock: jax.Array  #: int32 primitive index (from 0) of this step's last primitive
    scored: jax.Array     #: bool, the episode ended here with success
    a_next: Any           #: int32 or None: Sarsa's next action in ``s_next``


class UpdateRule(NamedTuple):
    """A tabular update rule (module doc)."""

    name: str
    init: Callable    #: (num_envs, num_keys = S * A) -> state
    update: Callable  #: (q, state, Transition, hp) -> (q, state, td_abs)
    act: Callable     #: (state, chosen (E,)) -> action (E,)
    next_action: bool  #: the runner fills ``Transition.a_next`` (Sarsa)


def _learn_mask(t: Transition) -> Any:
    """Transitions that update: the truncation weight and, async, the ended actions."""
    if t.advance is None:
        return t.weight
    return t.advance if t.weight is None else t.advance & t.weight


def _td_abs(delta: jax.Array, weight: Any) -> jax.Array:
    n = (jnp.float32(delta.shape[0]) if weight is None
         else jnp.sum(weight.astype(jnp.float32)))
    return jnp.sum(jnp.abs(delta)) / jnp.maximum(n, 1.0)


def _keep(state: Any, chosen: jax.Array) -> jax.Array:
    return chosen


def _one_step(duplicates: str) -> UpdateRule:
    def update(q, state, t: Transition, hp):
        w = _learn_mask(t)
        q, delta = q_update(q, t.s, t.a, t.r, t.s_boot, t.terminal, hp.learning_rate,
                            hp.discount, duplicates=duplicates, weight=w, num_primitives=t.n)
        return q, state, _td_abs(delta, w)

    return UpdateRule("q_learning", lambda e, k: (), update, _keep, False)


def _traces(kind: str, duplicates: str, length: int, truncation: str) -> UpdateRule:
    sarsa = kind == "sarsa"

    def update(q, tr, t: Transition, hp):
        w, a_boot = _learn_mask(t), None
        if sarsa:  # bootstrap from the next action; a time-limit end with final_obs: V
            a_boot = t.a_next
            if truncation == "bootstrap":
                a_boot = jnp.where(t.truncated, jnp.argmax(q[t.s_boot], axis=-1),
                                   t.a_next).astype(jnp.int32)
        new, delta, tr = trace_update(
            q, tr, t.s, t.a, t.r, t.s_boot, t.terminal, t.done, hp.learning_rate,
            hp.discount, hp.trace.lam, kind=kind, duplicates=duplicates, weight=w,
            num_primitives=t.n, a_boot=a_boot, advance=t.advance)
        if sarsa:
            tr = tr.replace(a_next=t.a_next)
        return new, tr, _td_abs(delta, w)

    def act(tr, chosen):  # Sarsa: the action picked at the end of the previous step
        return jnp.where(tr.a_next >= 0, tr.a_next, chosen) if sarsa else chosen

    return UpdateRule(kind, lambda e, k: trace_init(e, length), update, act, sarsa)


def _monte_carlo(length: int, truncation: str) -> UpdateRule:
    if truncation == "bootstrap":
        raise ParamError("the monte_carlo rule does not bootstrap; use "
                         "truncation='skip' or 'terminal'")

    def update(q, log, t: Transition, hp):
        log = mc_log(log, t.decided, t.s, t.a, t.clock)
        q, log, _ = mc_update(q, log, t.done, t.scored, t.last_clock, hp.learning_rate,
                              hp.discount, t.weight)
        return q, log, jnp.float32(0.0)

    return UpdateRule("monte_carlo", lambda e, k: mc_init(e, length, k), update, _keep, False)


def make_rule(name: str, *, duplicates: str = "mean", trace_length: int = 16,
              mc_length: int = 128, truncation: str = "skip") -> UpdateRule:
    """The update rule ``name`` (one of :data:`RULES`) with its static settings:
    ``duplicates`` ("mean"/"sum"), the trace window, the Monte Carlo log length and the
    truncation mode (Sarsa bootstraps a time-limit end from V; Monte Carlo rejects
    "bootstrap")."""
    if name == "q_learning":
        return _one_step(duplicates)
    if name in TRACE_KINDS:
        return _traces(name, duplicates, trace_length, truncation)
    if name == "monte_carlo":
        return _monte_carlo(mc_length, truncation)
    raise ParamError(f"update rule {name!r}; choose one of {list(RULES)}")
