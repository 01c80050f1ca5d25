"""Macro actions as an env wrapper: one action = repeat one primitive until the discrete
state changes.

:class:`MacroWrapper` wraps any gymnax-style env and a state function (obs -> int32
discrete state): an action holds its primitive until the discrete state differs from the
one it started in, the episode ends, or a cap on repeats is reached; the transition is
semi-Markov (reward ``sum_i discount**i r_i`` over the n primitives, bootstrap with
``discount**n``). Pure; vmaps over environments. Modes (static, :data:`MACRO_MODES`):
``"sync"`` runs the whole action in one ``step`` (a ``lax.while_loop``), ``"async"`` runs
one primitive of every env's running action per ``step``. ``info["macro"]`` reports per env
``decided``, ``ended``, ``start``, ``action``, ``reward``, ``num_primitives`` and
``next_state``.

See docs/agents.md, "Macro actions" (the modes, keys, episode ends, the stop rule).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from vbl.envs.wrappers import Wrapper
from vbl.params import ParamError, param

__all__ = ["MACRO_MODES", "STOP_RULE_NAMES", "MacroActionParams", "MacroEnvParams",
           "RunningAction", "MacroState", "MacroWrapper", "macro_env_params"]

#: How a batch of environments runs macro actions (static, see the module doc).
MACRO_MODES = ("sync", "async")
#: Names of the stop rules (``stop_on``): "state" (any change of the index) is built in;
#: "grid_search" comes with the grid space (``vbl.spaces.macro_action.STOP_RULES``).
STOP_RULE_NAMES = ("state", "grid_search")


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
                         "goal's side ignored)", static=True, choices=STOP_RULE_NAMES)
    mode: str = param("sync", doc="'sync': each runner step runs every env's whole action "
                      "(a vmapped loop as long as the longest action); 'async': each runner "
                      "step advances every env by one primitive and an env decides again "
                      "when its action ends (same transitions, ~max_repeats / mean action "
                      "length times cheaper; the runner's steps then count primitives)",
                      static=True, choices=MACRO_MODES)


@struct.dataclass
class MacroEnvParams:
    """Params of :class:`MacroWrapper` (traced; vmap them over learners)."""

    inner: Any            #: the wrapped env's params
    max_repeats: Any      #: int32 cap on primitives per action (>= 1)
    min_repeats: Any      #: int32 primitives run in any case (unless the episode ends)
    discount: Any         #: float32 per-primitive discount of the action's reward


def macro_env_params(inner: Any, macro: MacroActionParams, discount: Any) -> MacroEnvParams:
    """:class:`MacroEnvParams` from the inner params, a params section and the discount."""
    return MacroEnvParams(inner=inner, max_repeats=macro.max_repeats,
                          min_repeats=macro.min_repeats, discount=discount)


@struct.dataclass
class RunningAction:
    """One env's running macro action (async mode; add a leading axis when vmapped)."""

    action: jax.Array   #: int32 primitive being repeated
    start: jax.Array    #: int32 discrete state where the action started
    reward: jax.Array   #: float32 discounted reward so far, sum_i discount**i r_i
    weight: jax.Array   #: float32 discount**count
    count: jax.Array    #: int32 primitives done so far (0: the env decides at the next step)
    start_key: jax.Array  #: int32 stop key where the action started

    @staticmethod
    def none(shape: tuple = ()) -> RunningAction:
        """No running action (arrays of ``shape``): the env decides at the next step."""
        z = jnp.zeros(shape, jnp.int32)
        return RunningAction(action=z, start=z, reward=jnp.zeros(shape, jnp.float32),
                             weight=jnp.ones(shape, jnp.float32), count=z, start_key=z)


@struct.dataclass
class MacroState:
    """One env's state under :class:`MacroWrapper` (add a leading axis when vmapped)."""

    inner: Any              #: the wrapped env's state
    index: jax.Array        #: int32 discrete state of the current observation
    key: jax.Array          #: int32 stop key of the current observation
    running: RunningAction  #: async mode's running action (sync: always none)


def _zeros_like_struct(tree: Any) -> Any:
    return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), tree)


def _same_key(a: jax.Array) -> jax.Array:
    return jnp.asarray(a, jnp.int32)


class MacroWrapper(Wrapper):
    """One step = one macro action (sync) or one primitive of the running one (async).

    Args:
      env: gymnax-style env (auto-reset) of one environment.
      state_fn: obs -> int32 discrete state.
      macro: its static fields choose the behaviour (``enabled``, ``mode``, ``stop_on``);
        the traced ones come with the step's :class:`MacroEnvParams`.
      stop_key: int32 perceived state -> int32 key; an action stops when the key changes
        (default: the perceived state itself). Required when ``macro.stop_on`` is not
        "state".
      perceive_fn: obs -> int32 what the state map perceives of the world (default
        ``state_fn``): the stop key is ``stop_key(perceive_fn(obs))``.
    """

    def __init__(self, env: Any, state_fn: Callable, macro: MacroActionParams,
                 stop_key: Callable | None = None, perceive_fn: Callable | None = None):
        super().__init__(env)
        if macro.mode not in MACRO_MODES:
            raise ParamError(f"macro.mode={macro.mode!r}; choose one of {list(MACRO_MODES)}")
        if stop_key is None and macro.stop_on != "state":
            raise ParamError(f"macro.stop_on={macro.stop_on!r} needs its stop_key function")
        self.state_fn, self.macro = state_fn, macro
        self.stop_key = _same_key if stop_key is None else stop_key
        self.perceive_fn = state_fn if perceive_fn is None else perceive_fn

    @property
    def is_async(self) -> bool:
        """Each step is one primitive of a running action (``enabled`` and mode "async")."""
        return self.macro.enabled and self.macro.mode == "async"

    def index(self, obs: Any) -> jax.Array:
        """int32 discrete state of one observation."""
        return jnp.asarray(self.state_fn(obs), jnp.int32)

    def key(self, obs: Any) -> jax.Array:
        """int32 stop key of one observation (an action ends when it changes)."""
        return jnp.asarray(self.stop_key(jnp.asarray(self.perceive_fn(obs), jnp.int32)),
                           jnp.int32)

    def reset(self, key: jax.Array, params: MacroEnvParams):
        obs, st = self.env.reset(key, params.inner)
        return obs, MacroState(st, self.index(obs), self.key(obs), RunningAction.none())

    def step(self, key: jax.Array, state: MacroState, action, params: MacroEnvParams):
        if self.is_async:
            return self._step_async(key, state, action, params)
        if self.macro.enabled:
            return self._step_sync(key, state, action, params)
        obs, st, r, term, trunc, info = self.env.step(key, state.inner, action, params.inner)
        r = jnp.asarray(r, jnp.float32)
        s_next = self.index(obs)
        one, yes = jnp.int32(1), jnp.bool_(True)
        info = {**info, "macro": dict(decided=yes, ended=yes, start=state.index,
                                      action=jnp.asarray(action, jnp.int32), reward=r,
                                      num_primitives=one, next_state=s_next)}
        return (obs, state.replace(inner=st, index=s_next, key=self.key(obs)), r,
                jnp.asarray(term, bool),
                jnp.asarray(trunc, bool), info)

    def _step_sync(self, key, state: MacroState, action, params: MacroEnvParams):
        """The whole action in a while loop; primitive i uses ``fold_in(key, i)``."""
        step_fn, ep = self.env.step, params.inner
        s0, k0 = state.index, state.key
        gamma = jnp.asarray(params.discount, jnp.float32)
        cap = jnp.asarray(params.max_repeats, jnp.int32)
        least = jnp.minimum(jnp.asarray(params.min_repeats, jnp.int32), cap)
        out_shape = jax.eval_shape(step_fn, key, state.inner, action, ep)
        obs0, _, _, term0, trunc0, info0 = _zeros_like_struct(out_shape)
        init = dict(env_state=state.inner, obs=obs0, reward=jnp.float32(0.0),
                    weight=jnp.float32(1.0), n=jnp.int32(0), terminated=term0.astype(bool),
                    truncated=trunc0.astype(bool), info=info0, s=s0, k=k0)

        def cond(c):
            unchanged = (c["k"] == k0) | (c["n"] < least)
            moving = unchanged & ~(c["terminated"] | c["truncated"]) & (c["n"] < cap)
            return (c["n"] == 0) | moving

        def body(c):
            obs, st, r, term, trunc, info = step_fn(jax.random.fold_in(key, c["n"]),
                                                    c["env_state"], action, ep)
            return dict(env_state=st, obs=obs,
                        reward=c["reward"] + c["weight"] * jnp.asarray(r, jnp.float32),
                        weight=c["weight"] * gamma, n=c["n"] + 1,
                        terminated=jnp.asarray(term, bool), truncated=jnp.asarray(trunc, bool),
                        info=info, s=self.index(obs), k=self.key(obs))

        c = jax.lax.while_loop(cond, body, init)
        yes = jnp.bool_(True)
        info = {**c["info"], "macro": dict(decided=yes, ended=yes, start=s0,
                                           action=jnp.asarray(action, jnp.int32),
                                           reward=c["reward"], num_primitives=c["n"],
                                           next_state=c["s"])}
        return (c["obs"], state.replace(inner=c["env_state"], index=c["s"], key=c["k"]),
                c["reward"],
                c["terminated"], c["truncated"], info)

    def _step_async(self, key, state: MacroState, action, params: MacroEnvParams):
        """One primitive of the running action (``action`` only where the env decides);
        the returned reward is the primitive's."""
        run = state.running
        decided = run.count == 0
        action = jnp.where(decided, jnp.asarray(action, jnp.int32), run.action)
        start = jnp.where(decided, state.index, run.start)
        start_key = jnp.where(decided, state.key, run.start_key)
        obs, st, r, term, trunc, info = self.env.step(key, state.inner, action, params.inner)
        s_next, k_next = self.index(obs), self.key(obs)
        r = jnp.asarray(r, jnp.float32)
        reward = run.reward + run.weight * r
        weight = run.weight * jnp.asarray(params.discount, jnp.float32)
        count = run.count + 1
        cap = jnp.asarray(params.max_repeats, jnp.int32)
        least = jnp.minimum(jnp.asarray(params.min_repeats, jnp.int32), cap)
        changed = k_next != start_key
        term, trunc = jnp.asarray(term, bool), jnp.asarray(trunc, bool)
        ended = term | trunc | (changed & (count >= least)) | (count >= cap)
        # ended: none, the env decides at the next step
        running = RunningAction(action=action, start=start, reward=reward, weight=weight,
                                count=count, start_key=start_key)
        running = jax.tree.map(lambda f, n: jnp.where(ended, f, n), RunningAction.none(),
                               running)
        new = MacroState(inner=st, index=s_next, key=k_next, running=running)
        info = {**info, "macro": dict(decided=decided, ended=ended, start=start, action=action,
                                      reward=reward, num_primitives=count, next_state=s_next)}
        return obs, new, r, term, trunc, info
