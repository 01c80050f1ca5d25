"""State maps: the discrete state spaces the paper compares, behind one protocol, so that one
tabular learner (:mod:`vbl.programs.tabular`) learns on each.

A :class:`StateMap` turns the task's env into the env the learner steps and an
observation of that env into a Q-table index:

* ``num_states``: S, the number of discrete states (static);
* ``env``: the env the learner steps (the task's env itself, or the task's env under the
  wrappers that build the state, e.g. a history filter and a quantiser);
* ``prepare(key, c)``: the map's fitted parameters for one learner (a pytree; pure, keyed;
  ``()`` for a map with nothing to fit), from the learner's experiment config ``c``;
* ``env_params(fitted, env_params)``: the params of ``env`` from the fitted parameters and
  the task's env params;
* ``index(obs, c)``: int32 state in [0, S) of one observation of ``env``;
* ``perceived(obs, c)``: int32 key of what the map perceives of the world; a macro action
  (one primitive repeated until "the state changed") ends when it changes. A map whose
  index also holds the learner's own commands (the CVA state) leaves them out here, so
  issuing a command does not by itself end the action;
* ``describe(fitted)``: float32 metrics of the fitted map (the identification's lags and
  orders), reported with the learner's final metrics.

Maps: :class:`GridMap` (the programmer's 319-state grid of Section 2's shooting task) and
:class:`CVAMap` (Table 2's state vectors of the two-robot task: the current image features,
the CVA state, or both in one compilation; under
:class:`~vbl.envs.wrappers.BallVelocityOracle` the ball's true velocity joins the
features). Each map reads its own config section: ``c.grid`` for the grid, ``c.cva`` and
``c.env`` for the CVA map.
"""

from __future__ import annotations

from typing import Any, Protocol

import jax
import jax.numpy as jnp

from vbl.agents.cva_state import (
    CVAStateParams,
    check_collection,
    command_dim,
    filtered_env,
    filtered_params,
    prepare_state,
    state_count,
)
from vbl.params import validate
from vbl.spaces.grid import NUM_GRID_STATES, grid_state

__all__ = ["StateMap", "GridMap", "CVAMap"]

F32 = jnp.float32


class StateMap(Protocol):
    """A discrete state space of one tabular learner (see the module docstring)."""

    num_states: int
    env: Any

    def prepare(self, key: jax.Array, c: Any) -> Any: ...

    def env_params(self, fitted: Any, env_params: Any) -> Any: ...

    def index(self, obs: Any, c: Any) -> jax.Array: ...

    def perceived(self, obs: Any, c: Any) -> jax.Array: ...

    def describe(self, fitted: Any) -> dict[str, jax.Array]: ...


class GridMap:
    """The programmer's 319-state grid (:func:`vbl.spaces.grid.grid_state`) on the Section 2
    features of ``env``; boundaries from the learner's ``c.grid`` (traced, sweepable).
    Nothing to fit; the grid perceives exactly its state."""

    num_states = NUM_GRID_STATES

    def __init__(self, env: Any):
        self.env = env

    def prepare(self, key: jax.Array, c: Any) -> tuple:
        return ()

    def env_params(self, fitted: tuple, env_params: Any) -> Any:
        return env_params

    def index(self, obs: jax.Array, c: Any) -> jax.Array:
        return grid_state(obs, c.grid)

    def perceived(self, obs: jax.Array, c: Any) -> jax.Array:
        return self.index(obs, c)

    def describe(self, fitted: tuple) -> dict[str, jax.Array]:
        return {}


class CVAMap:
    """Table 2's state vectors on ``env`` (the two-robot env, or it under
    :class:`~vbl.envs.wrappers.BallVelocityOracle`): the Figure 11 pipeline of
    :mod:`vbl.agents.cva_state` with the static fields of ``p`` (the config's ``cva``
    section): random-action collection, one CVA model per object, the history filter and
    the quantiser, fitted per learner by ``prepare`` (traced fields from ``c.cva``, the
    collection at ``c.env``). ``perceived``: the index of the state vector without its
    command terms (the current features are their own)."""

    def __init__(self, env: Any, p: CVAStateParams):
        validate(p)
        self.m = command_dim(env)
        check_collection(env, p, self.m)
        self.num_states = state_count(env, p)
        self.base, self.p = env, p
        self.env = filtered_env(env, p, self.m)

    def prepare(self, key: jax.Array, c: Any) -> tuple:
        return prepare_state(self.base, self.p, self.m, key, c.cva, c.env)

    def env_params(self, fitted: tuple, env_params: Any) -> Any:
        return filtered_params(env_params, *fitted)

    def index(self, obs: dict, c: Any) -> jax.Array:
        return obs["index"]

    def perceived(self, obs: dict, c: Any) -> jax.Array:
        return obs["perceived"]

    def describe(self, fitted: tuple) -> dict[str, jax.Array]:
        out = {}
        for name, model in zip(self.p.objects, fitted[0], strict=False):
            out[f"lag_{name}"] = model.lag.astype(F32)
            out[f"n_{name}"] = model.n.astype(F32)
        return out
