"""What a deep-RL learner sees: current features, a stack of frames, or CVA states.

:class:`InputEnv` wraps a vbl env (gymnax style, ``step_env`` without auto-reset, e.g.
:class:`vbl.envs.shoot_pass.ShootPassEnv`) and replaces its observation by

* ``"current"``: the env's own observation y(t) (26,) (Section 3 features);
* ``"stack"``: the last ``frames`` observations [y(t), y(t-1), ...] concatenated
  (frames x 26,), an episode's first observation repeated at its start;
* ``"cva"``: the CVA state vector of the tabular learner of Table 2,
  ``[mu_ball, mu_goal, mu_other]`` (the ``state_vector`` of
  :func:`vbl.agents.cva_state.history_wrapper`, unquantised), filtered from the same
  histories of outputs and motor commands with the learner's own fitted models
  (:func:`prepare_models`);
* ``"select"``: all three, zero-padded to the longest, and the traced
  ``InputParams.index`` picks one per learner (one compilation for all inputs; the
  padding is constant 0 and carries no signal).

It has the API the brax adapter needs: ``reset_state`` / ``step_state`` (the wrapped env's
dynamics, auto-reset and draws, no observation; the step records the command and whether
the episode restarted) and ``observe(state, params, eps) -> (obs, state)`` (the wrapped
env's observation, then the stack and histories pushed with it, or begun afresh after a
restart), so a step observes once; and the gymnax-style ``reset`` / ``step_env``
(``step_env``: no auto-reset), ``num_actions``, ``observation_shape``, ``default_params``.
Its params (:class:`InputParams`) carry the per-learner CVA models, so they vmap over
learners.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from vbl.agents.cva_state import CVAStateParams, collect, history_wrapper, identify_object
from vbl.envs.wrappers import fresh_history
from vbl.params import ParamError

__all__ = ["INPUTS", "KINDS", "InputParams", "InputState", "InputEnv", "prepare_models"]

INPUTS = ("current", "stack", "cva")
#: InputEnv kinds: one input, or "select": all three, zero-padded to one length, the traced
#: ``InputParams.index`` picks one per learner (one compilation for all three inputs)
KINDS = (*INPUTS, "select")
F32 = jnp.float32


@struct.dataclass
class InputParams:
    """inner: the wrapped env's params; models: one CVA ObjectModel per object ('cva',
    'select'); index: () int32 into :data:`INPUTS` (kind 'select' only)."""

    inner: Any
    models: tuple = ()
    index: Any = 0

    @property
    def max_steps(self) -> int:
        return self.inner.max_steps


@struct.dataclass
class InputState:
    """inner: the wrapped env's state; stack: (frames, obs_dim) newest first ('stack');
    hist_y / hist_u: per object (lag, q) outputs / (lag, m) motor commands ('cva'), as of
    the last observation; u: (m,) float32 the command taken since ('cva'); start: () bool
    the inner state begins an episode (the next observation starts the stack and the
    histories afresh)."""

    inner: Any
    stack: Any = None
    hist_y: tuple = ()
    hist_u: tuple = ()
    u: Any = None
    start: Any = True


def _push(h: jax.Array, row: jax.Array) -> jax.Array:
    return jnp.roll(h, 1, axis=0).at[0].set(row.astype(F32))


class InputEnv:
    """``env`` seen through input ``kind`` (see the module docstring).

    Args:
      env: vbl env with ``obs_slices`` and ``info["u"]`` (for 'cva').
      kind: one of :data:`KINDS`. frames: observations stacked ('stack', >= 1).
      cva: the tabular learner's pipeline parameters (objects, n_used, CVA lags; 'cva').
      m: motor command dimension (``info["u"]``; 'cva').
    """

    def __init__(self, env: Any, kind: str, frames: int = 3, cva: CVAStateParams | None = None,
                 m: int = 2):
        if kind not in KINDS:
            raise ParamError(f"input kind={kind!r} is not allowed; choose one of {list(KINDS)}")
        if int(frames) < 1:
            raise ParamError(f"frames={frames} must be >= 1")
        if kind in ("cva", "select") and cva is None:
            raise ParamError(f"input {kind!r} needs the CVA pipeline parameters (cva=...)")
        self.env, self.kind, self.frames, self.m = env, kind, int(frames), int(m)
        self.num_actions = env.num_actions
        self.default_params = InputParams(env.default_params)
        self.use_stack = kind in ("stack", "select")
        self.use_cva = kind in ("cva", "select")
        self.cva = cva.replace(state="cva") if self.use_cva else None
        self.filtered = history_wrapper(env, self.cva, m) if self.use_cva else None

    def dims(self) -> dict[str, int]:
        """Observation length of each input."""
        d = int(self.env.observation_shape[0])
        out = {"current": d, "stack": self.frames * d}
        if self.use_cva:
            out["cva"] = int(sum(self.filtered.block_dims()))
        return out

    @property
    def observation_shape(self) -> tuple[int, ...]:
        dims = self.dims()
        return (max(dims.values()),) if self.kind == "select" else (dims[self.kind],)

    def validate(self, params: InputParams) -> InputParams:
        if hasattr(self.env, "validate"):
            self.env.validate(params.inner)
        return params

    def _advance(self, st: InputState, obs: jax.Array) -> InputState:
        """``st`` after observing ``obs`` (the wrapped env's): the stack and histories pushed
        with it, or begun afresh from it where ``st.start``."""
        start = jnp.asarray(st.start, bool)
        if self.use_stack:
            fresh = jnp.broadcast_to(obs.astype(F32), (self.frames,) + obs.shape)
            st = st.replace(stack=jnp.where(start, fresh, _push(st.stack, obs)))
        if self.use_cva:
            # the tabular learner's decision-time rule: row 1 = the command just taken, row 0 = 0
            hu, hy = self.filtered.advance(st.hist_u, st.hist_y, st.u, obs, start)
            st = st.replace(hist_u=hu, hist_y=hy)
        return st.replace(start=jnp.zeros((), bool))

    def _obs(self, obs: jax.Array, st: InputState, params: InputParams) -> jax.Array:
        out = {"current": obs.astype(F32)}
        if self.use_stack:
            out["stack"] = st.stack.reshape(-1)
        if self.use_cva:
            out["cva"] = self.filtered.state_vector(st.hist_u, st.hist_y, obs, params.models)
        if self.kind != "select":
            return out[self.kind]
        n = self.observation_shape[0]
        padded = jnp.stack([jnp.pad(out[k], (0, n - out[k].shape[0])) for k in INPUTS])
        return padded[jnp.asarray(params.index, jnp.int32)]

    def reset_state(self, key: jax.Array, params: InputParams) -> tuple[InputState, Any]:
        """(state, eps) of a fresh episode without the observation (:meth:`observe` begins
        the stack and histories from it)."""
        inner, eps = self.env.reset_state(key, params.inner)
        d = int(self.env.observation_shape[0])
        zero = jnp.zeros((d,), F32)
        st = InputState(inner, start=jnp.ones((), bool))
        if self.use_stack:
            st = st.replace(stack=jnp.zeros((self.frames, d), F32))
        if self.use_cva:
            hu, hy = fresh_history(zero, self.filtered.slices, self.filtered.lag, self.m)
            st = st.replace(hist_u=hu, hist_y=hy, u=jnp.zeros((self.m,), F32))
        return st, eps

    def step_state(self, key: jax.Array, state: InputState, action: jax.Array,
                   params: InputParams):
        """The wrapped env's ``step_state`` (auto-reset): (state, eps, reward, terminated,
        truncated, info); the state records the command and whether the episode restarted."""
        inner, eps, r, term, trunc, info = self.env.step_state(key, state.inner, action,
                                                               params.inner)
        st = state.replace(inner=inner, start=jnp.asarray(info["episode_done"], bool))
        if self.use_cva:
            st = st.replace(u=jnp.asarray(info["u"], F32))
        return st, eps, r, term, trunc, info

    def observe(self, state: InputState, params: InputParams, eps: Any
                ) -> tuple[jax.Array, InputState]:
        """(obs, state): the input of ``state`` (the wrapped env's ``get_obs`` with pixel
        noise ``eps``, then the stack and histories advanced with it)."""
        obs = self.env.get_obs(state.inner, params.inner, eps)
        st = self._advance(state, obs)
        return self._obs(obs, st, params), st

    def reset(self, key: jax.Array, params: InputParams):
        st, eps = self.reset_state(key, params)
        return self.observe(st, params, eps)

    def step_env(self, key: jax.Array, state: InputState, action: jax.Array,
                 params: InputParams):
        """One step without auto-reset: (obs, state, reward, terminated, truncated, info)."""
        obs, inner, r, term, trunc, info = self.env.step_env(key, state.inner, action,
                                                             params.inner)
        st = state.replace(inner=inner, start=jnp.zeros((), bool))
        if self.use_cva:
            st = st.replace(u=jnp.asarray(info["u"], F32))
        st = self._advance(st, obs)
        return self._obs(obs, st, params), st, r, term, trunc, info


def prepare_models(env: Any, key: jax.Array, cva: CVAStateParams, env_params: Any) -> tuple:
    """The tabular learner's CVA models for one learner: ``cva.collect_steps`` random-action
    steps, one model per object (:func:`vbl.agents.cva_state.identify_object`)."""
    data = collect(env, key, env_params, cva.collect_steps)
    slices = [env.obs_slices[o] for o in cva.objects]
    return tuple(identify_object(data["u"], data["obs"][:, sl], cva.ident, k, cva.keep_beyond_order)
                 for sl, k in zip(slices, cva.n_used_per_object(), strict=True))
