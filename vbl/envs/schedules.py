"""Non-stationary environment schedules: env params as a function of finished trials.

gymnax style: the schedule's numbers are an explicit params dataclass and
:func:`ball_radius_params` maps (env params, trials, schedule) to the env params of the
next primitive, so a learner's run loop (e.g. :func:`vbl.agents.segmentation_learner.run_updates`,
``params_fn(trials)``) changes the world without touching the env's code. Every function
is pure and traceable (trials may be traced).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import ParamError, param

__all__ = ["BallChangeParams", "ball_radius_at", "ball_radius_params"]


@struct.dataclass
class BallChangeParams:
    """Two sudden ball-size changes (Figure 9; trial = finished episodes of the learner)."""

    radius_0: float = param(0.16, doc="ball radius before the first change (a larger ball "
                            "than the world's 0.11 m: easier, so learning starts sooner)",
                            unit="m", gt=0.0)
    radius_1: float = param(0.12, doc="ball radius after the first change", unit="m", gt=0.0)
    radius_2: float = param(0.10, doc="ball radius after the second change (both changes "
                            "shrink the ball: a larger ball is easier, and gives no drop)",
                            unit="m", gt=0.0)
    change_trial_1: int = param(400, doc="trial of the first change (paper: both changes "
                                "'around trial 500')", source="P/C", ge=0)
    change_trial_2: int = param(750, doc="trial of the second change", source="P/C", ge=0)

    def check(self) -> None:
        if np.any(np.asarray(self.change_trial_2) < np.asarray(self.change_trial_1)):
            raise ParamError(f"change.change_trial_2={self.change_trial_2} must be >= "
                             f"change.change_trial_1={self.change_trial_1}")


def ball_radius_at(trials: jax.Array, p: BallChangeParams) -> jax.Array:
    """Ball radius (float32 (...), m) after ``trials`` (int (...)) finished trials: radius_0
    before trial ``change_trial_1``, radius_1 from it, radius_2 from ``change_trial_2``."""
    r = jnp.where(trials >= p.change_trial_2, p.radius_2,
                  jnp.where(trials >= p.change_trial_1, p.radius_1, p.radius_0))
    return jnp.asarray(r, jnp.float32)


def ball_radius_params(env_params: Any, trials: jax.Array, p: BallChangeParams) -> Any:
    """``env_params`` (with ``world.ball.radius``, e.g. ShootingParams) with the ball radius
    of :func:`ball_radius_at`."""
    world = env_params.world
    ball = world.ball.replace(radius=ball_radius_at(trials, p))
    return env_params.replace(world=world.replace(ball=ball))
