"""Present a vbl env (gymnax-1.0 style, discrete actions) as a ``brax.envs.base.Env``.

* Actions: brax passes a continuous vector of size ``action_size = env.num_actions``;
  the adapter takes the **argmax** as the discrete primitive index (logits/one-hot in,
  ties to the lowest index).
* Randomness: brax's ``step`` has no key, so the adapter keeps a PRNG key in
  ``state.info["rng"]`` and splits it every step.
* Episode ends: the adapter uses the env's ``step_env`` (no internal auto-reset) and sets
  ``done = terminated | truncated`` (float32), so brax's own wrappers
  (``brax.envs.wrappers.training.wrap``: Vmap, Episode, AutoReset) manage episodes.
  Note brax's ``AutoResetWrapper`` restarts from the *first* start drawn at ``reset``
  (its documented behaviour); call ``reset`` again for new starts, or use the vbl env's
  own ``step`` for a fresh draw at every reset.
* ``state.pipeline_state`` holds the vbl env state; ``metrics`` has ``success``;
  ``info`` has ``rng``, ``success``, ``truncated`` (float32).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

__all__ = ["BraxAdapter"]


class BraxAdapter(Env):
    """A brax Env around a vbl env (e.g. :class:`vbl.envs.shooting.ShootingEnv`).

    Args:
      env: object with ``reset(key, params)``, ``step_env(key, state, action, params)``,
        ``num_actions``, ``observation_shape``, ``default_params``, ``validate(params)``.
      params: env parameters (validated here); ``None`` uses ``env.default_params``.
    """

    def __init__(self, env: Any, params: Any = None):
        for attr in ("reset", "step_env", "num_actions", "observation_shape", "default_params"):
            if not hasattr(env, attr):
                raise TypeError(f"{type(env).__name__} is not a vbl env: it lacks {attr!r}")
        self.vbl_env = env
        self.params = env.default_params if params is None else params
        if hasattr(env, "validate"):
            env.validate(self.params)

    def reset(self, rng: jax.Array) -> State:
        """rng: a raw uint32 (2,) key (``jax.random.PRNGKey``; brax's wrappers take the batch
        shape from ``rng.shape[:-1]``, so use raw keys with them). Returns the brax State."""
        k_reset, k_next = jax.random.split(rng)
        obs, st = self.vbl_env.reset(k_reset, self.params)
        zero = jnp.zeros((), jnp.float32)
        return State(pipeline_state=st, obs=obs, reward=zero, done=zero,
                     metrics={"success": zero},
                     info={"rng": k_next, "success": zero, "truncated": zero})

    def step(self, state: State, action: jax.Array) -> State:
        """action: (num_actions,) float; the primitive is its argmax."""
        if action.shape != (self.action_size,):
            raise ValueError(f"action must have shape ({self.action_size},) (one score per "
                             f"primitive; argmax is taken), got {action.shape}")
        k_step, k_next = jax.random.split(state.info["rng"])
        index = jnp.argmax(action).astype(jnp.int32)
        obs, st, reward, terminated, truncated, info = self.vbl_env.step_env(
            k_step, state.pipeline_state, index, self.params)
        done = (terminated | truncated).astype(jnp.float32)
        success = info["success"].astype(jnp.float32)
        new_info = dict(state.info)
        new_info.update(rng=k_next, success=success, truncated=truncated.astype(jnp.float32))
        return state.replace(pipeline_state=st, obs=obs, reward=reward.astype(jnp.float32),
                             done=done, metrics={**state.metrics, "success": success},
                             info=new_info)

    @property
    def observation_size(self) -> int:
        shape = tuple(self.vbl_env.observation_shape)
        return shape[0] if len(shape) == 1 else shape

    @property
    def action_size(self) -> int:
        return int(self.vbl_env.num_actions)

    @property
    def backend(self) -> str:
        return "vbl"
