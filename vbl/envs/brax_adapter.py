"""Present a vbl env (gymnax style, discrete actions) as a ``brax.envs.base.Env``.

:class:`BraxAdapter` follows the conventions of brax's training wrappers: ``done`` is 1.0
only on termination and the env's time limit sets ``info["truncation"]`` (pass
``adapter.episode_length`` as brax's ``episode_length``); an action is an integer index
``()`` or a float vector ``(num_actions,)`` taken by argmax; a step observes once, the
state it ends in; with ``fresh_starts`` every episode under brax's ``AutoResetWrapper``
starts from a new draw; the start difficulty is ``info["difficulty"]`` () float32
(:func:`set_difficulty`) and the key ``info["rng"]``. Observations, rewards and flags are
float32, or with ``obs="pixels"`` the observation is the learner's camera image (H, W, 3)
uint8. ``state.pipeline_state`` holds the vbl env state; ``metrics`` has ``success``.

See docs/ppo.md, "The brax adapter" and docs/render.md, "Pixel observations".
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["BraxAdapter", "set_difficulty", "get_difficulty", "with_difficulty",
           "quiet_import"]


@contextlib.contextmanager
def quiet_import() -> Iterator[None]:
    """Import brax inside this: brax imports mujoco, which prints "Failed to import warp"
    on stdout when its optional GPU package warp is absent (the CPU install); that notice
    would mix with vbl's own output."""
    with contextlib.redirect_stdout(io.StringIO()):
        yield


with quiet_import():
    from brax.envs.base import Env, State

from vbl.envs.base import is_traced  # noqa: E402 - after brax's quiet import

F32 = jnp.float32
OBS_KINDS = ("features", "pixels")  #: what the adapter's observation is
DIFFICULTY_FIELD = "start_difficulty"  #: env params field a curriculum drives


def get_difficulty(params: Any) -> Any:
    """The ``start_difficulty`` of ``params`` or of its ``inner`` params (recursively);
    None when there is none."""
    while params is not None:
        if hasattr(params, DIFFICULTY_FIELD):
            return getattr(params, DIFFICULTY_FIELD)
        params = getattr(params, "inner", None)
    return None


def with_difficulty(params: Any, difficulty: Any) -> Any:
    """``params`` with its (or its ``inner`` params') ``start_difficulty`` replaced."""
    if hasattr(params, DIFFICULTY_FIELD):
        return params.replace(**{DIFFICULTY_FIELD: difficulty})
    if getattr(params, "inner", None) is not None:
        return params.replace(inner=with_difficulty(params.inner, difficulty))
    raise ValueError(f"{type(params).__name__} has no {DIFFICULTY_FIELD!r}")


def set_difficulty(state: State, difficulty: Any) -> State:
    """``state`` with ``info["difficulty"]`` set to ``difficulty`` (scalar or batch-shaped,
    in [0, 1]) for the starts drawn from now on."""
    if "difficulty" not in state.info:
        raise ValueError("this state has no info['difficulty']: the adapted task has no "
                         f"{DIFFICULTY_FIELD!r} parameter (ShootingEnv and ShootPassEnv have one)")
    old = state.info["difficulty"]
    info = dict(state.info)
    info["difficulty"] = jnp.broadcast_to(jnp.asarray(difficulty, F32), old.shape)
    return state.replace(info=info)


class BraxAdapter(Env):
    """A brax Env around a vbl env (:class:`~vbl.envs.shooting.ShootingEnv`,
    :class:`~vbl.envs.shoot_pass.ShootPassEnv`, or a wrapper with the same API).

    Args:
      env: object with ``reset_state(key, params) -> (state, eps)``, ``step_state(key,
        state, action, params) -> (state, eps, reward, terminated, truncated, info)``
        (auto-reset), ``get_obs(state, params, eps)`` (or ``observe``, see the module
        docstring), ``num_actions``, ``observation_shape``, ``default_params``.
      params: env parameters (validated when concrete); ``None`` uses ``env.default_params``.
        May be traced (e.g. per-learner params inside a vmapped program).
      fresh_starts: draw a new start for every episode under ``AutoResetWrapper``.
      obs: ``"features"`` (the env's observation, float32) or ``"pixels"`` (the learner's
        camera image (H, W, 3) uint8; the env needs ``get_pixels`` and ``image_shape``).
    """

    def __init__(self, env: Any, params: Any = None, fresh_starts: bool = True,
                 obs: str = "features"):
        for attr in ("reset_state", "step_state", "num_actions", "observation_shape",
                     "default_params"):
            if not hasattr(env, attr):
                raise TypeError(f"{type(env).__name__} is not a vbl env: it lacks {attr!r}")
        if obs not in OBS_KINDS:
            raise ValueError(f"obs={obs!r} is not allowed; choose one of {list(OBS_KINDS)}")
        if obs == "pixels" and not all(hasattr(env, a) for a in ("get_pixels", "image_shape")):
            raise TypeError(f"{type(env).__name__} has no camera image (get_pixels, "
                            "image_shape): obs='pixels' needs one")
        self.vbl_env = env
        self.obs_kind = obs
        self.params = env.default_params if params is None else params
        self.fresh_starts = bool(fresh_starts)
        if hasattr(env, "validate") and not is_traced(self.params):
            env.validate(self.params)

    # ------------------------------------------------------------------ metadata
    @property
    def has_difficulty(self) -> bool:
        """True when the task's params have a start difficulty a curriculum can drive."""
        return get_difficulty(self.params) is not None

    @property
    def episode_length(self) -> int:
        """The env's time limit (primitives): the ``episode_length`` for EpisodeWrapper."""
        return int(self.params.max_steps)

    @property
    def _obs_shape(self) -> tuple[int, ...]:
        if self.obs_kind == "pixels":
            return tuple(self.vbl_env.image_shape(self.params))
        return tuple(self.vbl_env.observation_shape)

    @property
    def observation_size(self) -> int | tuple[int, ...]:
        shape = self._obs_shape
        return shape[0] if len(shape) == 1 else shape

    @property
    def action_size(self) -> int:
        return int(self.vbl_env.num_actions)

    @property
    def backend(self) -> str:
        return "vbl"

    # ------------------------------------------------------------------ core
    def _params_at(self, difficulty: jax.Array | None) -> Any:
        if difficulty is None:
            return self.params
        return with_difficulty(self.params, difficulty)

    def reset_state(self, rng: jax.Array) -> tuple[State, Any]:
        """:meth:`reset` without the observation: (State whose ``obs`` is 0, eps); ``observe``
        of them is :meth:`reset`'s State."""
        k_reset, k_next = jax.random.split(rng)
        info = {"rng": k_next, "success": jnp.zeros((), F32), "truncation": jnp.zeros((), F32)}
        difficulty = None
        if self.has_difficulty:
            difficulty = jnp.asarray(get_difficulty(self.params), F32)
            info["difficulty"] = difficulty
        st, eps = self.vbl_env.reset_state(k_reset, self._params_at(difficulty))
        zero = jnp.zeros((), F32)
        obs = jnp.zeros(self._obs_shape, jnp.uint8 if self.obs_kind == "pixels" else F32)
        return State(pipeline_state=st, obs=obs, reward=zero, done=zero,
                     metrics={"success": zero}, info=info), eps

    def observe(self, state: State, eps: Any) -> State:
        """``state`` with the observation of its env state (pixel-noise normals ``eps``)."""
        if self.obs_kind == "pixels":
            img = self.vbl_env.get_pixels(state.pipeline_state, self.params, eps)
            return state.replace(obs=img)
        if hasattr(self.vbl_env, "observe"):
            obs, st = self.vbl_env.observe(state.pipeline_state, self.params, eps)
        else:
            st = state.pipeline_state
            obs = self.vbl_env.get_obs(st, self.params, eps)
        return state.replace(pipeline_state=st, obs=obs.astype(F32))

    def reset(self, rng: jax.Array) -> State:
        """rng: a raw uint32 (2,) key (brax's wrappers take the batch shape from
        ``rng.shape[:-1]``). Returns the brax State of a fresh episode."""
        return self.observe(*self.reset_state(rng))

    def _index(self, action: jax.Array) -> jax.Array:
        action = jnp.asarray(action)
        if action.shape == () and jnp.issubdtype(action.dtype, jnp.integer):
            if not is_traced(action) and not 0 <= int(action) < self.action_size:
                raise ValueError(f"action index must be in [0, {self.action_size}), got "
                                 f"{int(action)}")
            return action.astype(jnp.int32)
        if action.shape != (self.action_size,):
            raise ValueError(f"action must be an integer index () or a vector "
                             f"({self.action_size},) of scores (argmax is taken), got shape "
                             f"{action.shape} dtype {action.dtype}")
        return jnp.argmax(action).astype(jnp.int32)

    def step_state(self, state: State, action: jax.Array) -> tuple[State, Any]:
        """:meth:`step` without the observation: (State with the previous ``obs``, eps);
        ``observe`` of them is :meth:`step`'s State (without ``AutoResetWrapper``)."""
        index = self._index(action)
        k_step, k_start, k_next = jax.random.split(state.info["rng"], 3)
        st, eps, reward, terminated, truncated, info = self.vbl_env.step_state(
            k_step, state.pipeline_state, index, self.params)
        if self.fresh_starts and "first_pipeline_state" in state.info:
            fresh = self.vbl_env.reset_state(
                k_start, self._params_at(state.info.get("difficulty")))
            done = jnp.asarray(info["episode_done"], bool)
            st, eps = jax.tree.map(lambda a, b: jnp.where(done, a, b), fresh, (st, eps))
        success = jnp.asarray(info["success"]).astype(F32)
        new_info = dict(state.info)
        new_info.update(rng=k_next, success=success,
                        truncation=(truncated & ~terminated).astype(F32))
        return state.replace(pipeline_state=st, reward=jnp.asarray(reward).astype(F32),
                             done=jnp.asarray(terminated).astype(F32),
                             metrics={**state.metrics, "success": success},
                             info=new_info), eps

    def step(self, state: State, action: jax.Array) -> State:
        """One primitive. action: integer index () or scores (num_actions,)."""
        state = self.observe(*self.step_state(state, action))
        if self.fresh_starts and "first_pipeline_state" in state.info:
            info = dict(state.info)
            info.update(first_pipeline_state=state.pipeline_state, first_obs=state.obs)
            state = state.replace(info=info)
        return state
