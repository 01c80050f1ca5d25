"""Macro actions: one action = repeat one primitive until the discrete state changes.

The lab's earlier work fixed the "state-action deviation" of a coarse grid this
way: an action is a primitive held (repeated) until the robot's discrete state
differs from the one it started in, the episode ends, or a cap on repeats is
reached. :func:`macro_step` wraps any gymnax-style ``step`` and a state-index
function in a ``lax.while_loop``; it is pure and vmaps over environments (a
vmapped loop runs until every environment has stopped; the finished ones are
frozen by the loop's select).

The returned reward is the discounted sum ``sum_i discount**i * r_i`` over the n
primitives, so a semi-Markov Q-learning update bootstraps with ``discount**n``
(``vbl.agents.qlearning`` does). If the episode ends inside the repeat, the loop
stops at that primitive; the env's auto-reset has already drawn the next start, so
the returned ``obs`` / ``state`` belong to the new episode and ``info`` carries the
ended episode's facts, exactly as a single env step would.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from vbl.params import param

__all__ = ["MacroActionParams", "MacroOutcome", "MacroCarry", "MACRO_MODES", "STOP_RULES",
           "grid_search_key", "macro_step", "make_macro_step", "macro_carry_init",
           "async_macro_advance"]

#: How a batch of environments runs macro actions (static choice, see the module doc).
MACRO_MODES = ("sync", "async")


def grid_search_key(index: jax.Array) -> jax.Array:
    """Stop key of a 319-grid state index (int32, same shape): the index without the goal's
    orientation (a turn flips it by noise at close range) and without a lost goal's side,
    and, while the ball is lost, without the goal altogether. Two grid states with equal
    keys do not end a macro action under ``stop_on="grid_search"``."""
    from vbl.spaces.grid import NUM_BALL_STATES, NUM_GOAL_STATES

    i = jnp.asarray(index, jnp.int32)
    ball, goal = i // NUM_GOAL_STATES, i % NUM_GOAL_STATES
    lost_goal, lost_ball = NUM_GOAL_STATES - 2, NUM_BALL_STATES - 2
    goal = jnp.where(goal >= lost_goal, lost_goal, goal - goal % 3)  # drop orientation, side
    goal = jnp.where(ball >= lost_ball, lost_goal, goal)  # ball lost: the goal does not matter
    return (NUM_GOAL_STATES * ball + goal).astype(jnp.int32)


#: ``stop_on`` choices: state index -> key; a macro action stops when the key changes.
STOP_RULES: dict[str, Callable] = {"state": lambda i: jnp.asarray(i, jnp.int32),
                                   "grid_search": grid_search_key}


@struct.dataclass
class MacroActionParams:
    """Whether one action repeats its primitive until the discrete state changes."""

    enabled: bool = param(True, doc="repeat each primitive until the discrete state changes "
                          "(the earlier work's one action); off: one action = one primitive",
                          static=True)
    max_repeats: int = param(20, doc="cap on primitives per action (at the default 0.1 s "
                             "primitive: 2 s)", unit="primitives", ge=1)
    min_repeats: int = param(1, doc="primitives every action runs even if the state changed "
                             "earlier (unless the episode ends; capped at max_repeats); > 1 "
                             "damps one-primitive flips between look-alike states",
                             unit="primitives", ge=1)
    stop_on: str = param("state", doc="what ends an action: any change of the state index "
                         "('state'), or for the 319-state grid 'grid_search': changes that "
                         "matter (while the ball is lost only the ball reappearing; a lost "
                         "goal's side ignored)", static=True, choices=tuple(STOP_RULES))
    mode: str = param("sync", doc="'sync': each runner step runs every env's whole action "
                      "(a vmapped loop as long as the longest action); 'async': each runner "
                      "step advances every env by one primitive and an env decides again "
                      "when its action ends (same transitions, ~max_repeats / mean action "
                      "length times cheaper; the runner's steps then count primitives)",
                      static=True, choices=MACRO_MODES)


@struct.dataclass
class MacroOutcome:
    """Result of one macro action of one environment (add a leading axis when vmapped)."""

    obs: Any              #: observation after the last primitive (a new episode's if it ended)
    env_state: Any        #: env state after the last primitive
    reward: jax.Array     #: float32, sum_i discount**i r_i over the primitives
    terminated: jax.Array  #: bool, the episode ended by reaching a terminal state
    truncated: jax.Array  #: bool, the episode ended by its time limit
    info: Any             #: the env's info of the last primitive
    num_primitives: jax.Array  #: int32 n in 1..max_repeats
    next_state: jax.Array  #: int32 discrete state of ``obs``


def _zeros_like_struct(tree: Any) -> Any:
    return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), tree)


def macro_step(step_fn: Callable, state_index_fn: Callable, key: jax.Array, env_state: Any,
               state_index: jax.Array, action: jax.Array, env_params: Any, max_repeats: Any,
               discount: Any, min_repeats: Any = 1, stop_on: str = "state") -> MacroOutcome:
    """Repeat ``action`` from ``env_state`` (whose discrete state is ``state_index``).

    Args:
      step_fn: gymnax-style ``step(key, state, action, params) -> (obs, state, reward,
        terminated, truncated, info)`` of ONE environment (auto-reset).
      state_index_fn: obs -> int32 discrete state.
      key: PRNG key; primitive i uses ``fold_in(key, i)``.
      env_state, state_index: current env state and its discrete state (int32 scalar).
      action: int32 primitive to repeat.
      env_params: the env's params pytree.
      max_repeats: cap on primitives (int >= 1, may be traced).
      discount: per-primitive discount of the summed reward (may be traced).
      min_repeats: primitives run in any case (unless the episode ends first), capped at
        ``max_repeats`` (int >= 1, may be traced; default 1).
      stop_on: static key of :data:`STOP_RULES` ("state": any change of the index).

    Stops after the first primitive (at or after the ``min_repeats``-th) for which the
    stop key of the discrete state differs from that of ``state_index``, the episode ends,
    or ``max_repeats`` primitives ran.
    """
    if stop_on not in STOP_RULES:
        raise ValueError(f"stop_on={stop_on!r}; choose one of {list(STOP_RULES)}")
    key_of = STOP_RULES[stop_on]
    s0 = jnp.asarray(state_index, jnp.int32)
    k0 = key_of(s0)
    gamma = jnp.asarray(discount, jnp.float32)
    cap = jnp.asarray(max_repeats, jnp.int32)
    least = jnp.minimum(jnp.asarray(min_repeats, jnp.int32), cap)
    out_shape = jax.eval_shape(step_fn, key, env_state, action, env_params)
    obs0, _, _, term0, trunc0, info0 = _zeros_like_struct(out_shape)

    init = dict(env_state=env_state, obs=obs0, reward=jnp.float32(0.0),
                weight=jnp.float32(1.0), n=jnp.int32(0), terminated=term0.astype(bool),
                truncated=trunc0.astype(bool), info=info0, s=s0)

    def cond(c):
        unchanged = (key_of(c["s"]) == k0) | (c["n"] < least)
        moving = unchanged & ~(c["terminated"] | c["truncated"]) & (c["n"] < cap)
        return (c["n"] == 0) | moving

    def body(c):
        obs, st, r, term, trunc, info = step_fn(jax.random.fold_in(key, c["n"]), c["env_state"],
                                                action, env_params)
        return dict(env_state=st, obs=obs,
                    reward=c["reward"] + c["weight"] * jnp.asarray(r, jnp.float32),
                    weight=c["weight"] * gamma, n=c["n"] + 1,
                    terminated=jnp.asarray(term, bool), truncated=jnp.asarray(trunc, bool),
                    info=info, s=jnp.asarray(state_index_fn(obs), jnp.int32))

    c = jax.lax.while_loop(cond, body, init)
    return MacroOutcome(obs=c["obs"], env_state=c["env_state"], reward=c["reward"],
                        terminated=c["terminated"], truncated=c["truncated"], info=c["info"],
                        num_primitives=c["n"], next_state=c["s"])


def make_macro_step(step_fn: Callable, state_index_fn: Callable) -> Callable:
    """``f(key, env_state, state_index, action, env_params, max_repeats, discount,
    min_repeats=1, stop_on="state") -> MacroOutcome``: :func:`macro_step` bound to an env's
    ``step`` and a state function."""

    def f(key, env_state, state_index, action, env_params, max_repeats, discount,
          min_repeats=1, stop_on="state"):
        return macro_step(step_fn, state_index_fn, key, env_state, state_index, action,
                          env_params, max_repeats, discount, min_repeats, stop_on)

    return f


@struct.dataclass
class MacroCarry:
    """Per-environment state of the running macro actions (async mode), each (E,)."""

    action: jax.Array  #: int32 primitive being repeated
    start: jax.Array   #: int32 discrete state where the action started
    reward: jax.Array  #: float32 discounted reward so far, sum_i discount**i r_i
    weight: jax.Array  #: float32 discount**k
    count: jax.Array   #: int32 primitives done so far (0: the env decides at this step)


def macro_carry_init(num_envs: int) -> MacroCarry:
    """No running action in any of ``num_envs`` environments."""
    z = jnp.zeros((num_envs,), jnp.int32)
    return MacroCarry(action=z, start=z, reward=jnp.zeros((num_envs,), jnp.float32),
                      weight=jnp.ones((num_envs,), jnp.float32), count=z)


def async_macro_advance(carry: MacroCarry, state_index: jax.Array, chosen: jax.Array,
                        step_out: Callable, max_repeats: Any, discount: Any,
                        min_repeats: Any = 1, stop_on: str = "state"):
    """One primitive of every environment's running action (async mode).

    Args:
      carry: :class:`MacroCarry` (E,) before this primitive.
      state_index: (E,) int32 discrete state now (before the primitive).
      chosen: (E,) int32 actions the policy chose now; used only where ``carry.count == 0``
        (the env decides), elsewhere the running action continues.
      step_out: ``action (E,) -> (obs, env_state, reward, terminated, truncated, info,
        next_state)`` of one primitive in every env (the caller's vmapped env step).
      max_repeats, discount, min_repeats, stop_on: as :func:`macro_step`.

    Returns ``(out, ended, transition, new_carry)``: ``out`` the step outputs; ``ended``
    (E,) bool, the action ended at this primitive (state key changed after at least
    ``min_repeats`` primitives, episode end, or ``max_repeats``); ``transition`` =
    ``(start, action, reward, num_primitives, decided)`` (E,) each, valid where ``ended``
    (``decided``: the env chose a new action at this step); ``new_carry`` reset where ended.
    """
    if stop_on not in STOP_RULES:
        raise ValueError(f"stop_on={stop_on!r}; choose one of {list(STOP_RULES)}")
    key_of = STOP_RULES[stop_on]
    decided = carry.count == 0
    action = jnp.where(decided, jnp.asarray(chosen, jnp.int32), carry.action)
    start = jnp.where(decided, jnp.asarray(state_index, jnp.int32), carry.start)
    out = step_out(action)
    obs, env_state, r, term, trunc, info, s_next = out
    reward = carry.reward + carry.weight * jnp.asarray(r, jnp.float32)
    weight = carry.weight * jnp.asarray(discount, jnp.float32)
    count = carry.count + 1
    cap = jnp.asarray(max_repeats, jnp.int32)
    least = jnp.minimum(jnp.asarray(min_repeats, jnp.int32), cap)
    changed = key_of(jnp.asarray(s_next, jnp.int32)) != key_of(start)
    ended = (jnp.asarray(term, bool) | jnp.asarray(trunc, bool) | (changed & (count >= least))
             | (count >= cap))
    fresh = macro_carry_init(action.shape[0])
    new = MacroCarry(action=action, start=start, reward=reward, weight=weight, count=count)
    new = jax.tree.map(lambda f, n: jnp.where(ended, f, n), fresh, new)
    return out, ended, (start, action, reward, count, decided), new
