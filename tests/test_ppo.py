"""The categorical distribution for brax's PPO against analytic values and scipy; brax's own
``ppo.train`` runs on every adapted task in the same process as ``import vbl``."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import special, stats

import vbl  # noqa: F401
from vbl.agents.ppo import (
    CategoricalDistribution,
    make_categorical_ppo_networks,
    network_size,
)
from vbl.agents.ppo_params import PPONetParams
from vbl.envs.brax_adapter import BraxAdapter
from vbl.envs.shoot_pass import ShootPassEnv
from vbl.envs.shooting import ShootingEnv

# logits log(1), log(2), log(3): probabilities 1/6, 2/6, 3/6
LOGITS = np.log(np.array([1.0, 2.0, 3.0]))
PROBS = np.array([1.0, 2.0, 3.0]) / 6.0


def test_log_prob_entropy_mode_analytic():
    d = CategoricalDistribution(3)
    assert d.param_size == 3
    logits = jnp.asarray(np.stack([LOGITS, LOGITS + 5.0]), jnp.float32)  # shift-invariant
    for a in range(3):
        lp = d.log_prob(logits, jnp.full((2,), a, jnp.int32))
        np.testing.assert_allclose(lp, np.log(PROBS[a]), rtol=1e-5)
    h = d.entropy(logits, jax.random.PRNGKey(0))
    h_true = -(1 / 6 * np.log(1 / 6) + 1 / 3 * np.log(1 / 3) + 1 / 2 * np.log(1 / 2))
    np.testing.assert_allclose(h, [h_true, h_true], rtol=1e-5)
    np.testing.assert_allclose(h_true, stats.entropy(PROBS), rtol=1e-12)  # the formula
    np.testing.assert_array_equal(d.mode(logits), [2, 2])
    uniform = d.entropy(jnp.zeros((9,)), jax.random.PRNGKey(0))
    np.testing.assert_allclose(uniform, np.log(9), rtol=1e-6)


def test_kl_matches_scipy():
    d = CategoricalDistribution(3)
    q = jnp.asarray([0.3, -1.0, 2.0])
    kl = d.create_dist(q).kl_divergence(d.create_dist(jnp.asarray(LOGITS)))  # KL(p || q)
    np.testing.assert_allclose(kl, special.rel_entr(PROBS, special.softmax(q)).sum(),
                               rtol=1e-5)


def test_samples_follow_the_probabilities():
    d = CategoricalDistribution(3)
    n = 20000
    a = d.sample(jnp.broadcast_to(jnp.asarray(LOGITS, jnp.float32), (n, 3)),
                 jax.random.PRNGKey(4))
    assert a.dtype == jnp.int32 and a.shape == (n,)
    counts = np.bincount(np.asarray(a), minlength=3)
    assert stats.chisquare(counts, n * PROBS).pvalue > 1e-3


def test_network_factory_outputs_logits():
    net = PPONetParams(policy_hidden=(8,), value_hidden=(8, 8))
    nets = make_categorical_ppo_networks(5, 7, **net.kwargs())
    pp = nets.policy_network.init(jax.random.PRNGKey(0))
    logits = nets.policy_network.apply(None, pp, jnp.ones((4, 5)))
    assert logits.shape == (4, 7)
    n_params = sum(x.size for x in jax.tree.leaves(pp))
    assert n_params == network_size(5, 7, net)["policy"] == 5 * 8 + 8 + 8 * 7 + 7


def test_bad_input():
    with pytest.raises(ValueError, match="num_actions must be >= 1"):
        CategoricalDistribution(0)


TASKS = {"shooting": lambda: ShootingEnv(),
         "shoot": lambda: ShootPassEnv("shoot"),
         "pass": lambda: ShootPassEnv("pass")}


def _train_brax_ppo(task: str):
    from brax.training.agents.ppo import train as ppo

    env = TASKS[task]()
    adapter = BraxAdapter(env, env.default_params.replace(max_steps=20))
    factory = functools.partial(make_categorical_ppo_networks,
                                **PPONetParams(policy_hidden=(16,), value_hidden=(16,)).kwargs())
    _, params, metrics = ppo.train(
        adapter, num_timesteps=2560, episode_length=adapter.episode_length, num_envs=8,
        batch_size=8, num_minibatches=2, unroll_length=10, num_updates_per_batch=1,
        num_evals=2, num_eval_envs=8, network_factory=factory, seed=0)
    assert np.isfinite(metrics["eval/episode_reward"])
    assert 0.0 <= metrics["eval/episode_success"] <= adapter.episode_length


def test_brax_ppo_train_runs_on_shooting():
    """brax's own ppo.train, a few thousand steps, after `import vbl` (no x64 switch here)."""
    _train_brax_ppo("shooting")


@pytest.mark.slow
@pytest.mark.parametrize("task", ["shoot", "pass"])
def test_brax_ppo_train_runs_on_shoot_pass(task):
    _train_brax_ppo(task)
