"""Experience collection for the off-line, action-based construction (paper Section 2.1).

A *state* of the construction is a set of input vectors from which repeating **one kind**
of action primitive reaches the goal, or a state built before, whatever the number of
repetitions (:mod:`vbl.spaces.action_cells` builds the states from this experience,
:mod:`vbl.spaces.cell_refine` refines them in closed loop). This module holds what the
construction and its evaluation share:

* :func:`sec2_features`: the Section 2 observation normalised to ``[0, 1]``
  (:class:`FeatureParams`), optionally with the objects' lost sides as categorical
  features, read by :func:`pattern_of`.
* :func:`collect_experience`: ``episodes_per_action`` episodes per primitive in parallel
  environments, each holding its primitive for ``horizon`` steps (or until the episode
  ends); start situations are the env's random starts, optionally with a per-episode
  start difficulty drawn uniformly in ``[difficulty_lo, difficulty_hi]``
  (:class:`ExperienceParams`). Returns an :class:`Experience`.

A policy on these features is evaluated on fresh starts by :func:`vbl.envs.rollout.rollout`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import ParamError, param

__all__ = [
    "FeatureParams",
    "ExperienceParams",
    "Experience",
    "sec2_features",
    "pattern_of",
    "collect_experience",
    "reset_at_random_difficulty",
]

F32 = jnp.float32


@struct.dataclass
class FeatureParams:
    """Normalisation of the Section-2 observation to the unit cube (paper ranges)."""

    ball_size_max: float = param(270.0, doc="x1 ball diameter range [0, max]", unit="px",
                                 source="P", gt=0.0)
    ball_pos_max: float = param(270.0, doc="x2 ball position range [-max, max]", unit="px",
                                source="P", gt=0.0)
    goal_size_max: float = param(480.0, doc="x3 goal size range [0, max]", unit="px",
                                 source="P", gt=0.0)
    goal_pos_max: float = param(256.0, doc="x4 goal position range [-max, max]", unit="px",
                                source="P", gt=0.0)
    lost_sides: bool = param(True, doc="append the ball/goal lost side ((side + 1) / 2) as "
                             "features 6 and 7 (else 5 features)", static=True)

    @property
    def dim(self) -> int:
        return 7 if self.lost_sides else 5


def sec2_features(obs: jax.Array, p: FeatureParams | None = None) -> jax.Array:
    """Section-2 observation (..., 9) -> normalised features (..., p.dim) float32 in [0, 1].

    x1 / max, (x2 + max) / 2max, x3 / max, (x4 + max) / 2max, (x5 + 1) / 2, and when
    ``lost_sides``: (ball_lost_side + 1) / 2, (goal_lost_side + 1) / 2; clipped to [0, 1].
    """
    p = FeatureParams() if p is None else p
    o = jnp.asarray(obs, F32)
    f = [o[..., 0] / p.ball_size_max, (o[..., 1] + p.ball_pos_max) / (2 * p.ball_pos_max),
         o[..., 2] / p.goal_size_max, (o[..., 3] + p.goal_pos_max) / (2 * p.goal_pos_max),
         (o[..., 4] + 1.0) / 2.0]
    if p.lost_sides:
        f += [(o[..., 7] + 1.0) / 2.0, (o[..., 8] + 1.0) / 2.0]
    return jnp.clip(jnp.stack(f, axis=-1), 0.0, 1.0).astype(F32)


@struct.dataclass
class ExperienceParams:
    """Experience collection for the construction: episodes each holding one primitive."""

    episodes_per_action: int = param(1000, doc="episodes per action primitive (all run in "
                                     "parallel)", static=True, ge=1)
    horizon: int = param(100, doc="primitives held per episode (fewer when it ends)",
                         unit="steps", static=True, ge=1)
    difficulty_lo: float = param(0.0, doc="per-episode start difficulty drawn uniformly in "
                                 "[lo, hi] (envs with params.start_difficulty)", ge=0.0, le=1.0)
    difficulty_hi: float = param(1.0, doc="upper end of the start difficulty range",
                                 ge=0.0, le=1.0)

    def check(self) -> None:
        if np.any(np.asarray(self.difficulty_lo) > np.asarray(self.difficulty_hi)):
            raise ParamError(f"collect.difficulty_lo={self.difficulty_lo} must be <= "
                             f"collect.difficulty_hi={self.difficulty_hi}")


@struct.dataclass
class Experience:
    """x (A, N, T+1, D) float32 features before each step; valid (A, N, T+1) bool (inside
    the episode); goal (A, N, T) bool (step t scored). Episode group a held primitive a."""

    x: jax.Array
    valid: jax.Array
    goal: jax.Array


def pattern_of(x: jax.Array, categorical_dims: int, levels: int) -> jax.Array:
    """Categorical pattern (int32 (...)) of features x (..., D): the last
    ``categorical_dims`` features, each rounded to one of ``levels`` equally spaced values
    in [0, 1], read as digits base ``levels`` (0 when ``categorical_dims`` is 0)."""
    if categorical_dims == 0:
        return jnp.zeros(x.shape[:-1], jnp.int32)
    digits = jnp.clip(jnp.round(x[..., -categorical_dims:] * (levels - 1)), 0, levels - 1)
    base = (levels ** jnp.arange(categorical_dims, dtype=jnp.int32)).astype(F32)
    return jnp.sum(digits * base, axis=-1).astype(jnp.int32)


def reset_at_random_difficulty(env: Any, env_params: Any, k_d: jax.Array, k_reset: jax.Array,
                               lo: Any, hi: Any) -> tuple[jax.Array, Any, Any]:
    """``env.reset(k_reset, ...)`` with the start difficulty drawn uniformly in [lo, hi] from
    ``k_d`` when the env's params have ``start_difficulty`` (else the params as given).
    Returns (obs, state, the episode's env params)."""
    ep = env_params
    if hasattr(env_params, "start_difficulty"):
        ep = env_params.replace(start_difficulty=jax.random.uniform(k_d, (), F32, lo, hi))
    obs, st = env.reset(k_reset, ep)
    return obs, st, ep


def collect_experience(env: Any, env_params: Any, key: jax.Array,
                       feature_fn: Callable[[jax.Array], jax.Array], num_actions: int,
                       p: ExperienceParams | None = None) -> Experience:
    """Run ``episodes_per_action`` episodes per primitive, each holding it (jit-able).

    ``feature_fn(obs) -> (D,) float32`` normalises an observation; ``p`` defaults to
    ``ExperienceParams()``. Returns :class:`Experience` with A = ``num_actions`` groups."""
    p = ExperienceParams() if p is None else p
    n, t_len = p.episodes_per_action, p.horizon

    def episode(k, a):
        k_d, k_reset, k_run = jax.random.split(k, 3)
        obs, st, ep = reset_at_random_difficulty(env, env_params, k_d, k_reset,
                                                 p.difficulty_lo, p.difficulty_hi)

        def body(carry, kt):
            obs, st, alive = carry
            obs2, st2, _, term, trunc, info = env.step(kt, st, a, ep)
            out = (feature_fn(obs), alive, alive & info["success"])
            return (obs2, st2, alive & ~(term | trunc)), out

        (obs_t, _, alive_t), (xs, valid, goal) = jax.lax.scan(
            body, (obs, st, jnp.ones((), bool)), jax.random.split(k_run, t_len))
        x = jnp.concatenate([xs, feature_fn(obs_t)[None]], axis=0)
        valid = jnp.concatenate([valid, alive_t[None]], axis=0)
        return x.astype(F32), valid, goal

    keys = jax.random.split(key, num_actions * n).reshape(num_actions, n, -1)
    acts = jnp.broadcast_to(jnp.arange(num_actions, dtype=jnp.int32)[:, None], (num_actions, n))
    x, valid, goal = jax.vmap(jax.vmap(episode))(keys, acts)
    return Experience(x=x, valid=valid, goal=goal)

