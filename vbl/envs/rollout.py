"""First-episode rollouts and evaluation: how every learner and experiment scores a policy.

An evaluation counts, per env, only its **first** episode: whether it scored and how many
steps it took (a tabular learner evaluates through its own step instead:
:func:`vbl.agents.qlearning.evaluation_stats`).

* :func:`rollout`: ``num_episodes`` fresh starts in parallel (``vmap``), each run for
  ``max_steps`` steps (``lax.scan``) by ``policy(obs, policy_state, key) -> (action,
  policy_state)``; the policy state (e.g. the action being held) starts at
  ``policy_state`` in every episode. :func:`stateless` adapts ``policy(obs, key) ->
  action``; :func:`fresh_starts` gives the starts the episodes begin from.

Key stream of :func:`rollout` (callers' results depend on it): episode ``i`` takes
``k = split(key, num_episodes)[i]``, ``k_reset, k_run = split(k)``; step ``t`` takes
``k_t = split(k_run, max_steps)[t]``, ``k_policy, k_env = split(k_t)``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["stateless", "fresh_starts", "rollout"]

Policy = Callable[[jax.Array, Any, jax.Array], tuple[jax.Array, Any]]


def stateless(policy: Callable[[jax.Array, jax.Array], jax.Array]) -> Policy:
    """``policy(obs, key) -> action`` as a :func:`rollout` policy with an empty state."""
    return lambda obs, ps, key: (policy(obs, key), ps)


def fresh_starts(env: Any, env_params: Any, key: jax.Array,
                 num_episodes: int) -> tuple[jax.Array, Any]:
    """The (obs (num_episodes, ...), state) the episodes of :func:`rollout` with the same
    ``key`` start from."""
    return jax.vmap(lambda k: env.reset(jax.random.split(k)[0], env_params))(
        jax.random.split(key, num_episodes))


def rollout(env: Any, env_params: Any, key: jax.Array, policy: Policy, num_episodes: int,
            max_steps: int, policy_state: Any = ()) -> tuple[jax.Array, jax.Array]:
    """Run ``num_episodes`` episodes from fresh starts (parallel) with ``policy``.

    ``env`` has ``reset_state`` / ``step_state`` (auto-resetting, ``info["success"]``) and
    ``get_obs`` (:class:`vbl.envs.shooting.ShootingEnv`): each step observes its state
    inside the loop body, so the compiled rollout holds the env's camera once. Steps after
    the first episode ended do not count.
    Returns (success (num_episodes,) bool: the first episode scored within ``max_steps``,
    length (num_episodes,) int32: its steps, ``max_steps`` if it did not end).
    """
    def one(k):
        k0, k1 = jax.random.split(k)
        st, eps = env.reset_state(k0, env_params)

        def body(carry, kt):
            st, eps, ps, alive, ok, n = carry
            ka, ks = jax.random.split(kt)
            a, ps = policy(env.get_obs(st, env_params, eps), ps, ka)
            st2, eps2, _, term, trunc, info = env.step_state(ks, st, a, env_params)
            ok = ok | (alive & info["success"])
            n = n + alive.astype(jnp.int32)
            return (st2, eps2, ps, alive & ~(term | trunc), ok, n), None

        init = (st, eps, policy_state, jnp.ones((), bool), jnp.zeros((), bool),
                jnp.zeros((), jnp.int32))
        (*_, ok, n), _ = jax.lax.scan(body, init, jax.random.split(k1, max_steps))
        return ok, n

    return jax.vmap(one)(jax.random.split(key, num_episodes))
