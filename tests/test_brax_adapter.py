"""The brax adapter: brax's training wrapper stack runs a vbl env; argmax action mapping."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import Env
from brax.envs.wrappers import training

import vbl  # noqa: F401
from vbl.envs.brax_adapter import BraxAdapter
from vbl.envs.shooting import ShootingEnv


@pytest.fixture(scope="module")
def adapter():
    env = ShootingEnv()
    return BraxAdapter(env, env.default_params.replace(max_steps=50))


def test_training_wrap_stack_runs(adapter):
    assert isinstance(adapter, Env)
    assert adapter.action_size == 9 and adapter.observation_size == 9
    n, ep_len = 4, 6
    env = training.wrap(adapter, episode_length=ep_len)
    state = jax.jit(env.reset)(jax.random.split(jax.random.PRNGKey(0), n))
    first_obs = np.asarray(state.obs)
    assert state.obs.shape == (n, 9) and state.obs.dtype == jnp.float32
    step = jax.jit(env.step)
    for t in range(ep_len):
        state = step(state, jax.random.normal(jax.random.PRNGKey(t), (n, 9)))
        assert state.reward.shape == (n,) and np.all(np.isfinite(np.asarray(state.obs)))
    # EpisodeWrapper ends every episode at ep_len; AutoResetWrapper restores the first obs
    assert np.all(np.asarray(state.done) == 1.0)
    np.testing.assert_allclose(state.obs, first_obs)
    np.testing.assert_array_equal(state.info["episode_metrics"]["length"], ep_len)
    state = step(state, jnp.zeros((n, 9)))
    np.testing.assert_array_equal(state.info["steps"], 1)


def test_argmax_action_matches_env_step(adapter):
    s0 = adapter.reset(jax.random.PRNGKey(1))
    s1 = adapter.step(s0, jnp.eye(9)[8] * 3.0 - 1.0)
    k_step, _ = jax.random.split(s0.info["rng"])
    obs, st, *_ = adapter.vbl_env.step_env(k_step, s0.pipeline_state, jnp.int32(8),
                                           adapter.params)
    np.testing.assert_allclose(s1.obs, obs)
    np.testing.assert_allclose(s1.pipeline_state.world.robots, st.world.robots)
    assert s1.done.dtype == jnp.float32 and s1.reward.dtype == jnp.float32


def test_adapter_errors(adapter):
    s0 = adapter.reset(jax.random.PRNGKey(1))
    with pytest.raises(ValueError, match=r"\(9,\)"):
        adapter.step(s0, jnp.zeros(3))
    with pytest.raises(TypeError, match="not a vbl env"):
        BraxAdapter(object())
