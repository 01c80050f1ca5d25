"""Stop rules of macro actions (:class:`vbl.envs.macro.MacroWrapper`) that need a state
space: ``stop_on`` name -> function of the int32 state index giving the key whose change
ends an action."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from vbl.params import ParamError
from vbl.spaces.grid import NUM_BALL_STATES, NUM_GOAL_STATES

__all__ = ["STOP_RULES", "grid_search_key", "stop_key"]


def grid_search_key(index: jax.Array) -> jax.Array:
    """Stop key of a 319-grid state index (int32, same shape): the index without the goal's
    orientation (a turn flips it by noise at close range) and without a lost goal's side,
    and, while the ball is lost, without the goal altogether. Two grid states with equal
    keys do not end a macro action under ``stop_on="grid_search"``."""
    i = jnp.asarray(index, jnp.int32)
    ball, goal = i // NUM_GOAL_STATES, i % NUM_GOAL_STATES
    lost_goal, lost_ball = NUM_GOAL_STATES - 2, NUM_BALL_STATES - 2
    goal = jnp.where(goal >= lost_goal, lost_goal, goal - goal % 3)  # drop orientation, side
    goal = jnp.where(ball >= lost_ball, lost_goal, goal)  # ball lost: the goal does not matter
    return (NUM_GOAL_STATES * ball + goal).astype(jnp.int32)


#: ``stop_on`` choices (:data:`vbl.envs.macro.STOP_RULE_NAMES`): index -> key.
STOP_RULES: dict[str, Callable] = {"state": lambda i: jnp.asarray(i, jnp.int32),
                                   "grid_search": grid_search_key}


def stop_key(stop_on: str) -> Callable:
    """The key function of stop rule ``stop_on`` (a name in :data:`STOP_RULES`)."""
    if stop_on not in STOP_RULES:
        raise ParamError(f"stop_on={stop_on!r}; choose one of {list(STOP_RULES)}")
    return STOP_RULES[stop_on]
