"""Small gymnax-style JAX worlds for the state-space construction tests.

* :class:`LineWorld` (Section 2.1 test): a position ``p`` on the line ``[0, 1]``,
  primitives 0 = forward (``+step``) and 1 = backward (``-step``), the goal at the
  right end (``p >= 1``). Below ``flip_below`` the robot faces the other way (the
  primitives swap direction), which makes a second, hand-derivable state.
* :class:`TwoRegionWorld` (Section 2.2 test): a point ``x`` in ``[0, 1]^2``, four
  primitives ``+-e0, +-e1``; the change of ``x`` is ``step * gain * u`` with
  ``gain = gain_left`` for ``x0 < boundary`` and ``gain_right`` otherwise (one affine
  model per region); the goal is the corner ``x0 >= goal_lo and x1 >= goal_lo``.

* :class:`ChainEnv` (Q-learning tests): a deterministic chain ``0 .. n-1``, action 0
  left (a wall at 0), 1 right; reaching ``n - 1`` scores 1 and ends the episode; the
  start position is a function of the key and params (a subclass chooses it).

All follow the ``ShootingEnv`` API: ``reset(key, params) -> (obs, state)``,
``step(key, state, action, params) -> (obs, state, reward, terminated, truncated,
info)`` with auto-reset and ``info["success"]``; the two worlds also have its
``reset_state`` / ``step_state`` / ``get_obs`` (:class:`ObsInState`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import param

F32 = jnp.float32


@struct.dataclass
class LineParams:
    step: float = param(0.05, doc="distance moved per primitive", gt=0.0)
    flip_below: float = param(0.0, doc="primitives swap direction for p < flip_below",
                              ge=0.0, le=1.0)
    max_steps: int = param(100, doc="time limit", static=True, ge=1)


@struct.dataclass
class ToyState:
    x: jax.Array       # (D,) float32
    step: jax.Array    # () int32


class ObsInState:
    """``reset_state`` / ``step_state`` / ``get_obs`` of a toy world whose observation is
    its state's ``x`` (no observation noise: ``eps`` is None)."""

    def get_obs(self, state, params, eps):
        return state.x

    def reset_state(self, key, params):
        return self.reset(key, params)[1], None

    def step_state(self, key, state, action, params):
        _, st, r, term, trunc, info = self.step(key, state, action, params)
        return st, None, r, term, trunc, info


class LineWorld(ObsInState):
    """Position on a line, forward/backward, goal at p >= 1."""

    num_actions = 2
    action_labels = ("F", "B")

    @property
    def default_params(self) -> LineParams:
        return LineParams()

    def reset(self, key, params):
        x = jax.random.uniform(key, (1,), F32, 0.0, 1.0)
        return x, ToyState(x, jnp.zeros((), jnp.int32))

    def step(self, key, state, action, params):
        p = state.x[0]
        sign = jnp.where(action == 0, 1.0, -1.0).astype(F32)
        sign = jnp.where(p < params.flip_below, -sign, sign)
        p2 = jnp.maximum(p + jnp.asarray(params.step, F32) * sign, 0.0)
        success = p2 >= 1.0
        n = state.step + 1
        truncated = (n >= params.max_steps) & ~success
        done = success | truncated
        obs0, fresh = self.reset(key, params)
        nxt = ToyState(jnp.reshape(p2, (1,)).astype(F32), n)
        new = jax.tree_util.tree_map(lambda a, b: jnp.where(done, a, b), fresh, nxt)
        info = dict(success=success, episode_done=done, episode_length=n)
        return new.x, new, success.astype(F32), success, truncated, info


@struct.dataclass
class TwoRegionParams:
    step: float = param(0.02, doc="distance per primitive at gain 1", gt=0.0)
    boundary: float = param(0.5, doc="x0 of the region boundary", gt=0.0, lt=1.0)
    gain_left: float = param(1.0, doc="gain of the dynamics for x0 < boundary")
    gain_right: float = param(-1.0, doc="gain of the dynamics for x0 >= boundary")
    goal_lo: float = param(0.9, doc="goal corner: x0 and x1 >= goal_lo", gt=0.0, le=1.0)
    max_steps: int = param(200, doc="time limit", static=True, ge=1)


_DIRS = jnp.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]], F32)


class TwoRegionWorld(ObsInState):
    """Two regions of different affine dynamics in [0, 1]^2."""

    num_actions = 4
    action_labels = ("+x0", "-x0", "+x1", "-x1")

    @property
    def default_params(self) -> TwoRegionParams:
        return TwoRegionParams()

    def reset(self, key, params):
        x = jax.random.uniform(key, (2,), F32, 0.0, 1.0)
        return x, ToyState(x, jnp.zeros((), jnp.int32))

    def delta(self, x, action, params):
        """The noiseless change of x (2,) under ``action`` (before clipping to the box)."""
        gain = jnp.where(x[0] < params.boundary, params.gain_left, params.gain_right)
        return (jnp.asarray(params.step, F32) * gain.astype(F32) * _DIRS[action]).astype(F32)

    def step(self, key, state, action, params):
        x2 = jnp.clip(state.x + self.delta(state.x, action, params), 0.0, 1.0)
        success = jnp.all(x2 >= params.goal_lo)
        n = state.step + 1
        truncated = (n >= params.max_steps) & ~success
        done = success | truncated
        _, fresh = self.reset(key, params)
        new = jax.tree_util.tree_map(lambda a, b: jnp.where(done, a, b), fresh,
                                     ToyState(x2.astype(F32), n))
        info = dict(success=success, episode_done=done, episode_length=n)
        return new.x, new, success.astype(F32), success, truncated, info


@struct.dataclass
class ChainState:
    s: jax.Array  # () int32 position
    t: jax.Array  # () int32 steps in the episode


class ChainEnv:
    """The chain (module docstring); ``params`` needs ``max_steps``; obs = [s] float32.

    Subclasses set ``n``, ``default_params`` and :meth:`start`."""

    num_actions = 2
    n: int
    default_params = None

    def start(self, key, params) -> jax.Array:
        raise NotImplementedError

    def reset(self, key, params):
        s = self.start(key, params)
        return jnp.array([s], F32), ChainState(s=s, t=jnp.int32(0))

    def step(self, key, state, action, params):
        s2 = jnp.clip(state.s + jnp.where(action == 1, 1, -1), 0, self.n - 1).astype(jnp.int32)
        term = s2 == self.n - 1
        t = state.t + 1
        trunc = (t >= params.max_steps) & ~term
        done = term | trunc
        obs_r, st_r = self.reset(key, params)
        st = jax.tree.map(lambda a, b: jnp.where(done, a, b), st_r, ChainState(s=s2, t=t))
        obs = jnp.where(done, obs_r, jnp.array([s2], F32))
        return obs, st, term.astype(F32), term, trunc, {"success": term}


def assert_line_world_swap_map(m, num_states, classify, policy_action) -> None:
    """The hand-derived map of LineWorld with ``flip_below=0.5`` (primitives F = 0, B = 1):
    state F with 1 transition (division order 0) on p in [0.5, 1), state B with 2
    transitions (order 1) on [0, 0.5); checked away from p = 0.5 for any map type with
    ``action``, ``transitions``, ``order``, ``active`` per state and the given functions."""
    f, b = 0, 1
    assert int(num_states(m)) == 2
    by_action = {int(m.action[s]): s for s in np.flatnonzero(np.asarray(m.active))}
    assert set(by_action) == {f, b}
    assert int(m.transitions[by_action[f]]) == 1 and int(m.order[by_action[f]]) == 0
    assert int(m.transitions[by_action[b]]) == 2 and int(m.order[by_action[b]]) == 1
    right = jnp.linspace(0.56, 0.97, 12, dtype=jnp.float32)[:, None]
    left = jnp.linspace(0.03, 0.44, 12, dtype=jnp.float32)[:, None]
    assert np.all(np.asarray(classify(m, right)) == by_action[f])
    assert np.all(np.asarray(classify(m, left)) == by_action[b])
    assert np.all(np.asarray(policy_action(m, right)) == f)
    assert np.all(np.asarray(policy_action(m, left)) == b)
    assert classify(m, right).dtype == jnp.int32


def line_world_collector(episodes_per_action: int = 200, horizon: int = 40):
    """Jitted ``collect(key, flip_below) -> Experience`` on LineWorld (both primitives,
    identity features), as the Section 2.1 construction tests use it."""
    from vbl.spaces.action_based import ExperienceParams, collect_experience

    env = LineWorld()
    cp = ExperienceParams(episodes_per_action=episodes_per_action, horizon=horizon)
    return jax.jit(lambda k, flip: collect_experience(
        env, env.default_params.replace(flip_below=flip), k, lambda o: o, 2, cp))
