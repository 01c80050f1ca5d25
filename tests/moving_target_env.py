"""A tiny gymnax-style JAX env whose current observation is not Markov but a short history is.

"Strike a moving target with a delay": a target bounces between walls at ``-1`` and ``+1``
on a line with a hidden constant speed ``|v|`` in ``[speed_min, speed_max]`` (per step) and a
random direction. The learner observes the target position only (obs (1,)). Actions:
``0`` wait, ``1`` strike. A strike lands ``delay`` steps later; the episode ends at the
strike with reward 1 iff the target will then be within ``tol`` of the centre (the env
computes the future position analytically, including wall bounces). An episode without a
strike is truncated after ``max_steps`` steps (reward 0). ``reset`` draws a fresh target;
the automatic reset of ``step`` keeps the target's position and direction and draws a new
speed (so data collected over many episodes are continuous, like a ball rolling on).

From the position alone the direction of motion is unknown, so a memoryless policy succeeds
in at most about half of the episodes (``delay * speed_min > tol``); the last two positions
give position and velocity, with which the task is nearly always solvable. Used by the tests
of the CVA-state learner (``vbl.agents.cva_state``) as a stand-in for the rolling ball.

Interface as the two-robot env: ``num_actions``, ``default_params``, ``reset(key, params)``,
``step(key, state, action, params) -> (obs, state, reward, terminated, truncated, info)`` with
auto-reset, ``info["success"]``, ``info["u"]`` (the motor command, float32 (1,): -1 wait,
+1 strike; ``command_dim = 1``), ``obs_slices = {"target": slice(0, 1)}``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from vbl.params import param, validate


@struct.dataclass
class MovingTargetParams:
    speed_min: float = param(0.05, doc="smallest target speed", unit="1/step", gt=0.0)
    speed_max: float = param(0.08, doc="largest target speed", unit="1/step", gt=0.0)
    delay: int = param(6, doc="steps between a strike and its landing", unit="step", ge=1)
    tol: float = param(0.1, doc="success if |target| <= tol when the strike lands", gt=0.0)
    max_steps: int = param(40, doc="steps before an episode without a strike is truncated",
                           ge=1)
    obs_noise: float = param(0.0, doc="std of Gaussian noise on the observed position", ge=0.0)


@struct.dataclass
class MovingTargetState:
    pos: jax.Array  # float32 ()
    vel: jax.Array  # float32 ()
    t: jax.Array  # int32 () steps since the episode start


def fold(x: jax.Array) -> jax.Array:
    """Position on [-1, 1] after elastic bounces of an unconstrained coordinate x."""
    y = jnp.mod(x + 1.0, 4.0)
    return jnp.where(y <= 2.0, y - 1.0, 3.0 - y)


class MovingTargetEnv:
    num_actions = 2
    obs_dim = 1
    obs_slices = {"target": slice(0, 1)}
    command_dim = 1

    def __init__(self, params: MovingTargetParams | None = None):
        self.default_params = validate(params or MovingTargetParams())

    def get_obs(self, state, params, eps):
        """The observed position (1,); ``eps``: the key of its noise."""
        noise = params.obs_noise * jax.random.normal(eps, (1,), jnp.float32)
        return (state.pos[None] + noise).astype(jnp.float32)

    def _start(self, key, params):
        k_p, k_s, k_d = jax.random.split(key, 3)
        pos = jax.random.uniform(k_p, (), jnp.float32, -1.0, 1.0)
        speed = jax.random.uniform(k_s, (), jnp.float32, params.speed_min, params.speed_max)
        sign = jnp.where(jax.random.bernoulli(k_d), 1.0, -1.0).astype(jnp.float32)
        return MovingTargetState(pos, speed * sign, jnp.int32(0))

    def reset_state(self, key, params):
        """(state, eps) without the observation: ``get_obs(state, params, eps)`` is reset's."""
        k_s, k_o = jax.random.split(key)
        return self._start(k_s, params), k_o

    def reset(self, key, params):
        state, eps = self.reset_state(key, params)
        return self.get_obs(state, params, eps), state

    def step_state(self, key, state, action, params):
        """:meth:`step` without the observation: (state, eps, reward, terminated,
        truncated, info)."""
        k_reset, k_o = jax.random.split(key)
        strike = action == 1
        landing = fold(state.pos + state.vel * params.delay)
        success = strike & (jnp.abs(landing) <= params.tol)
        pos_next = fold(state.pos + state.vel)  # one step with bounces
        crossed = jnp.abs(state.pos + state.vel) > 1.0
        vel_next = jnp.where(crossed, -state.vel, state.vel)
        t = state.t + 1
        terminated = strike
        truncated = (~strike) & (t >= params.max_steps)
        done = terminated | truncated
        nxt = MovingTargetState(pos_next.astype(jnp.float32), vel_next.astype(jnp.float32), t)
        # the next episode continues the target's motion (a new speed, same direction), so
        # the collected y(t) has no jumps at episode starts
        fresh = self._start(k_reset, params)
        fresh = fresh.replace(pos=nxt.pos, vel=jnp.sign(nxt.vel) * jnp.abs(fresh.vel))
        new = jax.tree.map(lambda a, b: jnp.where(done, a, b), fresh, nxt)
        reward = success.astype(jnp.float32)
        info = {"success": success, "episode_length": t,
                "u": jnp.where(strike, 1.0, -1.0).astype(jnp.float32)[None]}
        return new, k_o, reward, terminated, truncated, info

    def step(self, key, state, action, params):
        new, eps, reward, terminated, truncated, info = self.step_state(key, state, action,
                                                                        params)
        return self.get_obs(new, params, eps), new, reward, terminated, truncated, info
