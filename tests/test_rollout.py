"""First-episode rollouts and evaluation (vbl.envs.rollout).

Truth: a NumPy loop over the episodes, one step at a time, with LineWorld's dynamics
written out (position p, primitive 0 moves +step, 1 moves -step, floor at 0, goal
p >= 1, time limit) and the key stream of the module docstring; the policies are given
functions of (obs, key), called per step.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from toy_worlds import LineWorld

from vbl.envs.rollout import fresh_starts, rollout, stateless

ENV = LineWorld()
EPISODES, MAX_STEPS, HOLD = 16, 30, 3


def _random_or_forward(obs, key):
    """F (B below p = 0.15), but a uniform primitive with probability 0.4."""
    k_coin, k_a = jax.random.split(key)
    rand = jax.random.randint(k_a, (), 0, 2, jnp.int32)
    own = jnp.where(obs[0] < 0.15, 1, 0)
    return jnp.where(jax.random.bernoulli(k_coin, 0.4), rand, own).astype(jnp.int32)


def _hold(obs, held, key):
    """A uniform primitive, drawn anew every HOLD steps and held in between."""
    a, n = held
    decide = n >= HOLD
    a = jnp.where(decide, jax.random.randint(key, (), 0, 2, jnp.int32), a)
    n = jnp.where(decide, 1, n + 1)
    return a, (a, n)


HOLD_INIT = (jnp.zeros((), jnp.int32), jnp.full((), HOLD, jnp.int32))


_draw = jax.jit(lambda key: jax.random.randint(key, (), 0, 2, jnp.int32))


def _hold_np(obs, held, key):
    """:func:`_hold` in plain Python ints."""
    a, n = held
    if n >= HOLD:
        a, n = int(_draw(key)), 0
    return a, (a, n + 1)


def _reference(key, params, decide_np, state0):
    """(success, length, starts) of the first episodes, one step at a time in NumPy.
    ``decide_np(obs, state, key) -> (int action, state)``."""
    step, ok, length, starts = np.float32(params.step), [], [], []
    for k in jax.random.split(key, EPISODES):
        k_reset, k_run = jax.random.split(k)
        p = np.float32(np.asarray(jax.random.uniform(k_reset, (1,), jnp.float32))[0])
        starts.append(p)
        state, scored, n = state0, False, 0
        for kt in jax.random.split(k_run, MAX_STEPS):
            k_pol, _ = jax.random.split(kt)
            a, state = decide_np(np.array([p], np.float32), state, k_pol)
            p = np.maximum(p + step * np.float32(1.0 if a == 0 else -1.0), np.float32(0.0))
            n += 1
            if p >= 1.0:
                scored = True
            if scored or n >= params.max_steps:
                break
        ok.append(scored)
        length.append(n)
    return np.array(ok), np.array(length), np.array(starts, np.float32)


@pytest.mark.parametrize("env_limit", [20, 100])   # below / above the rollout's MAX_STEPS
@pytest.mark.parametrize("kind", ["stateless", "held"])
def test_rollout_matches_a_numpy_loop(kind, env_limit):
    params = ENV.default_params.replace(max_steps=env_limit)
    key = jax.random.PRNGKey(11)
    if kind == "stateless":
        policy, state0 = stateless(_random_or_forward), ()
        act = jax.jit(_random_or_forward)
        decide_np = lambda o, s, k: (int(act(o, k)), s)  # noqa: E731
    else:
        policy, state0, decide_np = _hold, HOLD_INIT, _hold_np
    ok, length = jax.jit(lambda k: rollout(ENV, params, k, policy, EPISODES, MAX_STEPS,
                                           state0))(key)
    ok_ref, len_ref, starts = _reference(key, params, decide_np,
                                         (0, HOLD) if kind == "held" else ())
    assert ok.dtype == jnp.bool_ and length.dtype == jnp.int32
    np.testing.assert_array_equal(np.asarray(ok), ok_ref)
    np.testing.assert_array_equal(np.asarray(length), len_ref)
    assert 0 < ok_ref.sum() < EPISODES                    # both outcomes occur
    if env_limit > MAX_STEPS:                             # some episodes cut by the rollout
        assert np.any(len_ref == MAX_STEPS)
    np.testing.assert_array_equal(np.asarray(fresh_starts(ENV, params, key, EPISODES)[0])[:, 0],
                                  starts)


