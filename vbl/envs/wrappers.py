"""Env wrappers in the style of brax's wrapper stack, for gymnax-style envs.

A wrapped env has the same API as the env: ``reset(key, params) -> (obs, state)`` and
``step(key, state, action, params) -> (obs, state, reward, terminated, truncated, info)``
(auto-reset: after a finished step obs/state are the next episode's). Each wrapper holds the
inner env in ``env`` and forwards every attribute it does not define (``num_actions``,
``obs_slices``, ...). A wrapper with params of its own takes a params pytree whose ``inner``
field holds the inner env's params; one with state of its own keeps the inner state in
``inner``. Params are per learner (vmap them over learners).

* :class:`HistoryFilterWrapper`: keeps each observed object's raw input/output history and
  returns the state vector: the objects' filtered states (the filters are data in its
  params, applied by a function given at construction, by default :func:`linear_filter`)
  or their current features;
* :class:`FirstEpisodeWrapper`: counts the episodes finished since the reset and whether
  the first one succeeded (a first-episode evaluation reads them);
* :class:`QuantizeWrapper`: state vector -> ``{"index": int32 (), "state": (d,)}`` with a
  quantiser (data in its params, applied by a function given at construction);
* :class:`BallVelocityOracle`: a control, the two-robot env whose observation also holds
  the ball's true velocity.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from vbl.params import ParamError

__all__ = ["KINDS", "Wrapper", "LinearFilter", "linear_filter", "fresh_history",
           "push_history", "HistoryParams", "HistoryState", "HistoryFilterWrapper",
           "EpisodeCounts", "FirstEpisodeWrapper", "QuantizeParams", "QuantizeWrapper",
           "BallVelocityOracle"]

F32 = jnp.float32
#: State vectors of :class:`HistoryFilterWrapper` (static): "cva" the filtered states,
#: "current" the current features, "select" both with every object block zero-padded to one
#: size and the traced ``HistoryParams.use_filter`` picking one (one compilation for both).
KINDS = ("cva", "current", "select")


class Wrapper:
    """Holds ``env`` and forwards ``reset``, ``step`` and unknown attributes to it."""

    def __init__(self, env: Any):
        self.env = env

    def reset(self, key: jax.Array, params: Any):
        return self.env.reset(key, params)

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any):
        return self.env.step(key, state, action, params)

    @property
    def unwrapped(self) -> Any:
        """The innermost env."""
        return getattr(self.env, "unwrapped", self.env)

    def __getattr__(self, name: str) -> Any:
        if name == "env" or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.env, name)


# ---------------------------------------------------------------- histories and the filter


@struct.dataclass
class LinearFilter:
    """A linear filter of one object over ``lag`` past samples (normalised units).

    ``x = sum_j Uu[:, j] @ u_n(t-j) + Uy[:, j] @ y_n(t-j)``, j = 0 .. lag-1, with
    ``u_n = (u - u_mean) / u_scale`` (``u_n(t) = 0``: u(t) is not chosen yet) and
    ``y_n = (y - y_mean) / y_scale``.
    """

    Uu: jax.Array       # (k, lag, m)
    Uy: jax.Array       # (k, lag, q)
    u_mean: jax.Array   # (m,)
    u_scale: jax.Array  # (m,)
    y_mean: jax.Array   # (q,)
    y_scale: jax.Array  # (q,)


def linear_filter(filt: LinearFilter, hist_u: jax.Array, hist_y: jax.Array,
                  commands: bool = True) -> jax.Array:
    """Filtered state (k,) float32 from raw histories ``hist_u`` (lag, m) (row j = u(t-j);
    row 0 is ignored) and ``hist_y`` (lag, q) (row j = y(t-j)). ``commands=False`` (static)
    leaves out the command terms (every u at its data mean): the part of the state the
    outputs, i.e. the world, give."""
    un = (hist_u - filt.u_mean) / filt.u_scale
    un = un.at[0].set(0.0) if commands else jnp.zeros_like(un)
    yn = (hist_y - filt.y_mean) / filt.y_scale
    return (jnp.einsum("njm,jm->n", filt.Uu, un)
            + jnp.einsum("njq,jq->n", filt.Uy, yn)).astype(F32)


def fresh_history(obs: jax.Array, slices, lag: int, m: int) -> tuple[tuple, tuple]:
    """Histories at an episode start, per object: u (lag, m) zeros (the robot at rest) and
    y (lag, q) the first observation repeated."""
    hu = tuple(jnp.zeros((lag, m), F32) for _ in slices)
    hy = tuple(jnp.broadcast_to(obs[s], (lag, s.stop - s.start)).astype(F32) for s in slices)
    return hu, hy


def push_history(hist_u: tuple, hist_y: tuple, u: jax.Array, obs: jax.Array,
                 slices) -> tuple[tuple, tuple]:
    """Histories after command ``u`` (m,) led to ``obs``: row 1 of u = ``u``, row 0 = 0
    (the next command is not chosen yet); row 0 of y = the object's features in ``obs``."""
    hu = tuple(jnp.roll(h, 1, axis=0).at[1].set(u).at[0].set(0.0) for h in hist_u)
    hy = tuple(jnp.roll(h, 1, axis=0).at[0].set(obs[s].astype(F32))
               for h, s in zip(hist_y, slices, strict=True))
    return hu, hy


@struct.dataclass
class HistoryParams:
    """inner: the wrapped env's params; filters: one filter per object (empty for
    'current'); use_filter: () bool, kind 'select' only (True: filtered states)."""

    inner: Any
    filters: tuple = ()
    use_filter: Any = True


@struct.dataclass
class HistoryState:
    """inner: the wrapped env's state; hist_u / hist_y: per object (lag, m) / (lag, q) raw
    histories, row 0 newest."""

    inner: Any
    hist_u: tuple
    hist_y: tuple


class HistoryFilterWrapper(Wrapper):
    """Observation = the state vector ``[x_obj..., extra...]`` (d,) float32; with
    ``world=True`` the dict ``{"state": (d,), "world": (d,)}``, where "world" is the same
    vector without the command terms (what the state map perceives of the world; the
    current features are their own).

    Args:
      env: gymnax-style env with ``obs_slices`` and ``info["u"]`` (the command, (m,)).
      objects: names of ``env.obs_slices``, one filter each. lag: history length.
      m: command dimension. out_dims: each object's filter output size.
      kind: one of :data:`KINDS`. extra: ``obs_slices`` appended unfiltered.
      filter_fn: ``(filter, hist_u (lag, m), hist_y (lag, q), commands=True) -> (k,)``.
      world: also return the vector without command terms (static).
    """

    def __init__(self, env: Any, objects: tuple, lag: int, m: int, out_dims: tuple,
                 kind: str = "cva", extra: tuple = (),
                 filter_fn: Callable = linear_filter, world: bool = False):
        super().__init__(env)
        if kind not in KINDS:
            raise ParamError(f"state kind={kind!r} is not allowed; choose one of {list(KINDS)}")
        slices = env.obs_slices
        for name in tuple(objects) + tuple(extra):
            if name not in slices:
                raise ParamError(f"object {name!r} is not in the env's obs_slices; valid: "
                                 f"{sorted(slices)}")
        if len(out_dims) != len(objects):
            raise ParamError(f"out_dims={out_dims!r} needs one size per object {objects!r}")
        self.kind, self.lag, self.m, self.filter_fn = kind, int(lag), int(m), filter_fn
        self.world = bool(world)
        self.out_dims = tuple(int(k) for k in out_dims)
        self.slices = [slices[o] for o in objects]
        self.extra = [slices[o] for o in extra]

    def block_dims(self) -> tuple[int, ...]:
        """Sizes of the state vector's blocks: one per object (filtered: its out_dims;
        current: its features; 'select': the larger), then one per extra slice."""
        cur = [s.stop - s.start for s in self.slices]
        per = {"cva": self.out_dims, "current": cur,
               "select": [max(a, b) for a, b in zip(self.out_dims, cur, strict=True)]}
        return tuple(int(k) for k in per[self.kind]) + tuple(s.stop - s.start
                                                              for s in self.extra)

    def state_vector(self, hist_u, hist_y, obs, filters, use_filter=True,
                     commands: bool = True) -> jax.Array:
        """(d,) float32: the object blocks then the extra slices; kind 'select': each object
        block zero-padded to :meth:`block_dims` in both vectors, ``use_filter`` picks;
        ``commands=False``: the filtered blocks without their command terms."""
        extra = [obs[s].astype(F32) for s in self.extra]
        cur = [obs[s].astype(F32) for s in self.slices]
        if self.kind == "current":
            return jnp.concatenate(cur + extra)
        filt = [self.filter_fn(f, hu, hy, commands=commands).astype(F32) for f, hu, hy in
                zip(filters, hist_u, hist_y, strict=True)]
        if self.kind == "cva":
            return jnp.concatenate(filt + extra)
        dims = self.block_dims()
        pad = lambda v, k: jnp.pad(v, (0, k - v.shape[0]))  # noqa: E731
        filt = jnp.concatenate([pad(v, k) for v, k in zip(filt, dims, strict=False)] + extra)
        cur = jnp.concatenate([pad(v, k) for v, k in zip(cur, dims, strict=False)] + extra)
        return jnp.where(jnp.asarray(use_filter, bool), filt, cur)

    def advance(self, hist_u, hist_y, u, obs, restart) -> tuple[tuple, tuple]:
        """Histories after one step: pushed, or fresh from ``obs`` where ``restart``."""
        pu, py = push_history(hist_u, hist_y, jnp.asarray(u, F32), obs, self.slices)
        fu, fy = fresh_history(obs, self.slices, self.lag, self.m)
        return (tuple(jnp.where(restart, a, b) for a, b in zip(fu, pu, strict=True)),
                tuple(jnp.where(restart, a, b) for a, b in zip(fy, py, strict=True)))

    def _observe(self, hu, hy, obs, params: HistoryParams):
        x = self.state_vector(hu, hy, obs, params.filters, params.use_filter)
        if not self.world:
            return x
        return {"state": x, "world": self.state_vector(hu, hy, obs, params.filters,
                                                       params.use_filter, commands=False)}

    def reset(self, key: jax.Array, params: HistoryParams):
        obs, st = self.env.reset(key, params.inner)
        hu, hy = fresh_history(obs, self.slices, self.lag, self.m)
        return self._observe(hu, hy, obs, params), HistoryState(st, hu, hy)

    def step(self, key: jax.Array, state: HistoryState, action, params: HistoryParams):
        obs, st, r, term, trunc, info = self.env.step(key, state.inner, action, params.inner)
        hu, hy = self.advance(state.hist_u, state.hist_y, info["u"], obs, term | trunc)
        return self._observe(hu, hy, obs, params), HistoryState(st, hu, hy), r, term, trunc, info

    def replay(self, obs: jax.Array, u: jax.Array, start: jax.Array,
               params: HistoryParams) -> jax.Array:
        """State vectors (N, d) of a recorded run with the rule of :meth:`step`: ``obs``
        (N, obs_dim) y(t), ``u`` (N, m) the command after y(t), ``start`` (N,) bool y(t)
        begins an episode."""
        u_prev = jnp.concatenate([jnp.zeros_like(u[:1]), u[:-1]])

        def body(c, x):
            o, up, st = x
            hu, hy = self.advance(*c, up, o, st)
            return (hu, hy), self.state_vector(hu, hy, o, params.filters, params.use_filter)

        init = fresh_history(obs[0], self.slices, self.lag, self.m)
        return jax.lax.scan(body, init, (obs, u_prev, start))[1]


# ------------------------------------------------------------------- first-episode counts


@struct.dataclass
class EpisodeCounts:
    """inner: the wrapped env's state; episodes () int32 finished since the reset;
    first_success () bool: the first of them succeeded."""

    inner: Any
    episodes: jax.Array
    first_success: jax.Array


class FirstEpisodeWrapper(Wrapper):
    """Counts finished episodes (``terminated | truncated``) and the first one's
    ``info["success"]``; params pass through unchanged."""

    def reset(self, key: jax.Array, params: Any):
        obs, st = self.env.reset(key, params)
        return obs, EpisodeCounts(st, jnp.int32(0), jnp.bool_(False))

    def step(self, key: jax.Array, state: EpisodeCounts, action, params: Any):
        obs, st, r, term, trunc, info = self.env.step(key, state.inner, action, params)
        done = term | trunc
        success = jnp.asarray(info["success"], bool) & done
        first = jnp.where(done & (state.episodes == 0), success, state.first_success)
        new = EpisodeCounts(st, state.episodes + done.astype(jnp.int32), first)
        return obs, new, r, term, trunc, info


# ---------------------------------------------------------------------------- quantisation


@struct.dataclass
class QuantizeParams:
    """inner: the wrapped env's params; quantizer: the data of ``quantize_fn``."""

    inner: Any
    quantizer: Any


class QuantizeWrapper(Wrapper):
    """Observation ``{"index": quantize_fn(quantizer, x) int32 (), "state": x}`` for the inner
    observation ``x`` (d,); for an inner ``{"state": x, "world": w}`` (a
    :class:`HistoryFilterWrapper` with ``world``) also ``"perceived"``: the index of ``w``
    with the same quantiser. The state passes through unchanged."""

    def __init__(self, env: Any, quantize_fn: Callable):
        super().__init__(env)
        self.quantize_fn = quantize_fn

    def _obs(self, x: Any, params: QuantizeParams) -> dict[str, jax.Array]:
        if isinstance(x, dict):
            return {"index": self.quantize_fn(params.quantizer, x["state"]),
                    "perceived": self.quantize_fn(params.quantizer, x["world"]),
                    "state": x["state"]}
        return {"index": self.quantize_fn(params.quantizer, x), "state": x}

    def reset(self, key: jax.Array, params: QuantizeParams):
        x, st = self.env.reset(key, params.inner)
        return self._obs(x, params), st

    def step(self, key: jax.Array, state: Any, action, params: QuantizeParams):
        x, st, r, term, trunc, info = self.env.step(key, state, action, params.inner)
        return self._obs(x, params), st, r, term, trunc, info


# ----------------------------------------------------------------------- a control env


class BallVelocityOracle(Wrapper):
    """A control, not the paper's method: the two-robot env
    (:class:`vbl.envs.shoot_pass.ShootPassEnv`) whose observation also holds the ball's true
    velocity in the learner's frame (forward, lateral; m/s), zero while the ball is not in
    the learner's image, right after the ball's features: the ball's slice grows by 2 (so a
    quantiser puts the velocity in the ball's codes) and the slices after it move by 2."""

    def __init__(self, env: Any):
        super().__init__(env)
        ball = env.obs_slices["ball"]
        self._end = ball.stop
        self.obs_slices = {k: sl if sl.stop <= ball.start else
                           slice(sl.start + 2, sl.stop + 2) for k, sl in env.obs_slices.items()}
        self.obs_slices["ball"] = slice(ball.start, ball.stop + 2)
        self.observation_shape = (env.observation_shape[0] + 2,)

    def get_obs(self, state, params, noise) -> jax.Array:
        obs = self.env.get_obs(state, params, noise)
        me = self.env.roles(params)[0]
        th = state.world.robots[me, 2]
        v = state.world.ball_vel
        c, s = jnp.cos(th), jnp.sin(th)
        seen = obs[self.env.obs_slices["visible"].start]  # the ball's visibility flag
        vel = jnp.stack([c * v[0] + s * v[1], -s * v[0] + c * v[1]]) * seen
        return jnp.concatenate([obs[:self._end], vel.astype(obs.dtype), obs[self._end:]])

    def reset(self, key, params=None):
        params = self.env.default_params if params is None else params
        state, noise = self.env.reset_state(key, params)
        return self.get_obs(state, params, noise), state

    def step(self, key, state, action, params=None):
        params = self.env.default_params if params is None else params
        state, noise, reward, terminated, truncated, info = self.env.step_state(
            key, state, action, params)
        return self.get_obs(state, params, noise), state, reward, terminated, truncated, info
