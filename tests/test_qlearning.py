"""Batched tabular Q-learning: convergence to value iteration, batch = loop of single updates,
duplicate rule, exploration schedules vs optax, action selection, parameter errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax import struct
from reference.qlearning_np import (
    epsilon_greedy_np,
    q_update_batch_loop,
    q_update_one,
    value_iteration,
)

import vbl  # noqa: F401
from tests import toy_worlds
from vbl.agents import (
    ExplorationParams,
    QRunnerParams,
    ScheduleParams,
    init_q,
    learner_keys,
    make_qlearning_runner,
    q_update,
    schedule_value,
    select_action,
    stack_for_learners,
)
from vbl.agents.exploration import boltzmann_probs, greedy_action, to_optax
from vbl.agents.lem import LEMParams
from vbl.envs.macro import MacroActionParams
from vbl.params import ParamError, validate

# ------------------------------------------------------------------ a tiny chain MDP
N_CHAIN = 5  # states 0..4; moving right from 3 into 4 scores and ends the episode


def chain_tables():
    """NumPy tables of the deterministic chain: action 0 left, 1 right."""
    nxt = np.zeros((N_CHAIN, 2), int)
    rew = np.zeros((N_CHAIN, 2))
    term = np.zeros((N_CHAIN, 2), bool)
    for s in range(N_CHAIN):
        nxt[s, 0] = max(s - 1, 0)
        nxt[s, 1] = min(s + 1, N_CHAIN - 1)
        for a in (0, 1):
            if nxt[s, a] == N_CHAIN - 1:
                rew[s, a], term[s, a] = 1.0, True
    return nxt, rew, term


@struct.dataclass
class ChainParams:
    max_steps: int = 40


class ChainEnv(toy_worlds.ChainEnv):
    """gymnax-style chain: auto-reset to a uniform start in 0..3."""

    n = N_CHAIN
    default_params = ChainParams()

    def start(self, key, params):
        return jax.random.randint(key, (), 0, N_CHAIN - 1, jnp.int32)


def chain_state_fn(obs):
    return obs[..., 0].astype(jnp.int32)


def test_synchronous_sweeps_converge_to_value_iteration():
    """Full sweeps of q_update over all (s, a), vmapped over (lr, discount) learners."""
    nxt, rew, term = chain_tables()
    lrs = jnp.array([0.25, 0.5, 1.0], jnp.float32)
    gammas = jnp.array([0.8, 0.5, 0.9], jnp.float32)
    s_all, a_all = np.meshgrid(np.arange(N_CHAIN), np.arange(2), indexing="ij")
    s_all, a_all = s_all.ravel(), a_all.ravel()
    args = (jnp.asarray(s_all), jnp.asarray(a_all), jnp.asarray(rew[s_all, a_all]),
            jnp.asarray(nxt[s_all, a_all]), jnp.asarray(term[s_all, a_all]))

    def sweeps(lr, gamma):
        def body(q, _):
            return q_update(q, *args, lr, gamma)[0], None
        return jax.lax.scan(body, jnp.zeros((N_CHAIN, 2), jnp.float32), None, length=300)[0]

    q = jax.jit(jax.vmap(sweeps))(lrs, gammas)
    assert q.dtype == jnp.float32
    for i, g in enumerate(np.asarray(gammas)):
        np.testing.assert_allclose(q[i], value_iteration(nxt, rew, term, float(g)), atol=1e-5)


@pytest.fixture(scope="module")
def chain_runner():
    expl = ExplorationParams(schedule="constant", init_value=1.0)
    params = QRunnerParams(
        num_states=N_CHAIN, num_actions=2, exploration=expl,
        macro=MacroActionParams(enabled=False), lem=LEMParams(enabled=False),
        num_envs=16, chunk_steps=200)
    return make_qlearning_runner(ChainEnv(), chain_state_fn, params), params


def test_runner_converges_to_value_iteration(chain_runner):
    """Random behaviour (epsilon 1), 3 learners sweeping the discount: Q -> Q*."""
    runner, params = chain_runner
    gammas = np.array([0.8, 0.5, 0.9], np.float32)
    bp = stack_for_learners(params, 3)
    bp = bp.replace(discount=jnp.asarray(gammas))
    ep = stack_for_learners(ChainEnv.default_params, 3)
    carry = runner.init_batch(learner_keys(0, 3), bp, ep)
    for _ in range(3):
        carry, metrics = runner.run_chunk_batch(carry, bp, ep)
    assert carry.q.dtype == jnp.float32 and carry.q.shape == (3, N_CHAIN, 2)
    assert metrics["episodes"].shape == (3, 200)
    nxt, rew, term = chain_tables()
    for i, g in enumerate(gammas):
        np.testing.assert_allclose(carry.q[i, :N_CHAIN - 1],
                                   value_iteration(nxt, rew, term, float(g))[:N_CHAIN - 1],
                                   atol=1e-4)
    # every finished episode with reward was a success; counters are consistent
    assert int(carry.episodes.sum()) > 0
    assert np.all(np.asarray(metrics["successes"]) <= np.asarray(metrics["episodes"]))
    np.testing.assert_array_equal(metrics["primitives"], metrics["actions"])  # no macro


def test_greedy_evaluation_after_learning(chain_runner):
    runner, params = chain_runner
    bp = stack_for_learners(params, 3)  # same shapes as above: no new compilation
    ep = stack_for_learners(ChainEnv.default_params, 3)
    carry = runner.init_batch(learner_keys(1, 3), bp, ep)
    carry, _ = runner.run_chunk_batch(carry, bp, ep)
    q = jnp.concatenate([carry.q[:2], jnp.zeros_like(carry.q[2:])])  # learner 2: untrained
    res = runner.evaluate_batch(learner_keys(2, 3), q, bp, ep, 20)
    np.testing.assert_allclose(res["success_rate"][:2], 1.0)  # greedy walks right in <= 4
    assert np.all(np.asarray(res["mean_primitives"][:2]) <= N_CHAIN - 1)
    # all-zero table: ties everywhere -> a random walk, which often needs more than 4 steps
    assert float(res["mean_primitives"][2]) > float(np.max(res["mean_primitives"][:2]))


# ------------------------------------------------------ batch update == loop of updates


def _random_batch(rng, n, n_s, n_a):
    return (rng.integers(0, n_s, n), rng.integers(0, n_a, n), rng.normal(size=n),
            rng.integers(0, n_s, n), rng.random(n) < 0.2)


@pytest.mark.parametrize("rule", ["mean", "sum"])
@pytest.mark.parametrize("table_states", [6, 600], ids=["small-table", "large-table"])
def test_batched_update_equals_loop_reference(rule, table_states):
    """40 transitions on 18 pairs (many duplicates), in a table of 6 or 600 states (the
    duplicate counts by a table-sized scatter or by comparing the transitions pairwise)."""
    rng = np.random.default_rng(0)
    n_s, n_a, n = 6, 3, 40
    q0 = rng.normal(size=(table_states, n_a)).astype(np.float32)
    s, a, r, s2, term = _random_batch(rng, n, n_s, n_a)
    weight = rng.random(n) < 0.8
    n_prim = rng.integers(1, 4, n)
    got, _ = q_update(jnp.asarray(q0), s, a, r, s2, term, 0.3, 0.7, duplicates=rule,
                      weight=jnp.asarray(weight), num_primitives=jnp.asarray(n_prim))
    want = q_update_batch_loop(q0, s, a, r, s2, term, 0.3, 0.7, rule, weight, n_prim)
    assert got.dtype == jnp.float32
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_distinct_pairs_equal_sequential_single_updates():
    """No duplicates, and no next state among the updated ones: order does not matter."""
    rng = np.random.default_rng(1)
    q0 = rng.normal(size=(8, 4)).astype(np.float32)
    s = np.array([0, 1, 2, 3, 0, 1])
    a = np.array([0, 1, 2, 3, 3, 2])
    s2 = np.array([5, 6, 7, 5, 6, 7])
    r = rng.normal(size=6)
    term = np.array([False, True, False, False, True, False])
    seq = np.array(q0, np.float64)
    for i in range(6):
        q_update_one(seq, s[i], a[i], r[i], s2[i], term[i], 0.25, 0.8)
    for rule in ("mean", "sum"):
        got, _ = q_update(jnp.asarray(q0), s, a, r, s2, term, 0.25, 0.8, duplicates=rule)
        np.testing.assert_allclose(got, seq, rtol=1e-6, atol=1e-6)


def test_duplicate_rule_analytic():
    """Three envs hit (0, 1) with terminal rewards 1, 0, 0.5 from Q = 0.2."""
    q0 = jnp.full((2, 2), 0.2, jnp.float32)
    s, a = jnp.array([0, 0, 0]), jnp.array([1, 1, 1])
    r, s2, term = jnp.array([1.0, 0.0, 0.5]), jnp.array([1, 1, 1]), jnp.array([True] * 3)
    lr = 0.25
    mean_q, _ = q_update(q0, s, a, r, s2, term, lr, 0.8, duplicates="mean")
    sum_q, _ = q_update(q0, s, a, r, s2, term, lr, 0.8, duplicates="sum")
    np.testing.assert_allclose(mean_q[0, 1], 0.2 + lr * (0.5 - 0.2), rtol=1e-6)  # mean target
    np.testing.assert_allclose(sum_q[0, 1], 0.2 + lr * (0.8 + -0.2 + 0.3), rtol=1e-6)
    for qq in (mean_q, sum_q):  # nothing else moved
        np.testing.assert_array_equal(np.delete(np.asarray(qq).ravel(), 1), np.float32(0.2))


def test_q_update_reads_traced_params():
    p = QRunnerParams(num_states=3, num_actions=2)
    q = init_q(p)
    assert q.shape == (3, 2) and q.dtype == jnp.float32
    sweep = stack_for_learners(p, 2).replace(learning_rate=jnp.array([0.5, 1.0]),
                                             discount=jnp.array([0.0, 0.5]))
    f = jax.vmap(lambda pp: q_update(q.at[2].set(1.0), jnp.array([0]), jnp.array([1]),
                                     jnp.array([0.0]), jnp.array([2]), jnp.array([False]),
                                     pp.learning_rate, pp.discount)[0])
    out = f(sweep)
    np.testing.assert_allclose(out[:, 0, 1], [0.0, 0.5])


# ------------------------------------------------------------------------ exploration


@pytest.mark.parametrize("kind,extra", [
    ("constant", {}), ("linear", dict(transition_begin=10.0)),
    ("exponential", dict(decay_rate=0.3, transition_begin=5.0)),
    ("exponential", dict(decay_rate=0.3, staircase=True)), ("cosine", {})])
def test_schedules_match_optax(kind, extra):
    p = ScheduleParams(schedule=kind, init_value=0.9, end_value=0.05, transition_steps=100.0,
                       **extra)
    counts = np.array([0, 1, 5, 10, 50, 99, 100, 101, 150, 400])
    want = np.array([float(to_optax(p)(int(c))) for c in counts])
    got = jax.jit(schedule_value)(p, jnp.asarray(counts))
    assert got.dtype == jnp.float32
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)


def test_schedule_numbers_are_traced_and_sweepable():
    p = ScheduleParams(schedule="linear", init_value=1.0, end_value=0.0)
    sweep = stack_for_learners(p, 2).replace(transition_steps=jnp.array([10.0, 20.0]))
    vals = jax.jit(jax.vmap(schedule_value, in_axes=(0, None)))(sweep, 5)
    np.testing.assert_allclose(vals, [0.5, 0.75])
    ref = [float(optax.linear_schedule(1.0, 0.0, t)(5)) for t in (10, 20)]
    np.testing.assert_allclose(vals, ref)


def test_greedy_tie_breaking_uniform():
    q_row = jnp.array([1.0, 3.0, 0.0, 3.0, 3.0], jnp.float32)
    n = 6000
    acts = greedy_action(jax.random.PRNGKey(0), jnp.broadcast_to(q_row, (n, 5)))
    assert acts.dtype == jnp.int32
    freq = np.bincount(np.asarray(acts), minlength=5) / n
    np.testing.assert_allclose(freq, [0, 1 / 3, 0, 1 / 3, 1 / 3], atol=0.03)
    # the same key gives the same choice; another key may differ
    np.testing.assert_array_equal(acts, greedy_action(jax.random.PRNGKey(0),
                                                      jnp.broadcast_to(q_row, (n, 5))))


def test_epsilon_greedy_and_boltzmann_frequencies():
    q_row = np.array([0.0, 1.0, 0.5], np.float32)
    n = 8000
    rows = jnp.broadcast_to(jnp.asarray(q_row), (n, 3))
    eps = select_action(jax.random.PRNGKey(1), rows, 0.3, "epsilon_greedy")
    rng = np.random.default_rng(0)
    ref = [epsilon_greedy_np(rng, q_row, 0.3) for _ in range(n)]
    np.testing.assert_allclose(np.bincount(np.asarray(eps), minlength=3) / n,
                               np.bincount(ref, minlength=3) / n, atol=0.03)
    np.testing.assert_allclose(np.bincount(np.asarray(eps), minlength=3) / n,
                               [0.1, 0.8, 0.1], atol=0.03)
    t = 0.5
    bz = select_action(jax.random.PRNGKey(2), rows, t, "boltzmann")
    want = np.exp(q_row / t) / np.exp(q_row / t).sum()
    np.testing.assert_allclose(np.bincount(np.asarray(bz), minlength=3) / n, want, atol=0.03)
    np.testing.assert_allclose(boltzmann_probs(jnp.asarray(q_row), t), want, rtol=1e-5)
    # tiny temperature: no overflow, greedy
    assert np.all(np.isfinite(np.asarray(boltzmann_probs(jnp.asarray(q_row) * 1e4, 1e-3))))


# ---------------------------------------------------------------------- bad parameters


@pytest.mark.parametrize("field,value,match", [
    ("learning_rate", 0.0, "learning_rate"), ("learning_rate", 1.5, "learning_rate"),
    ("discount", 1.0, "discount"), ("discount", -0.1, "discount"),
    ("num_states", 0, "num_states"), ("num_actions", 0, "num_actions")])
def test_bad_agent_params(field, value, match):
    p = QRunnerParams(lem=LEMParams(enabled=False)).replace(**{field: value})
    with pytest.raises(ParamError, match=match):
        make_qlearning_runner(ChainEnv(), chain_state_fn, p)


def test_bad_learner_counts_and_exploration():
    for n in (0, -1):
        with pytest.raises(ParamError, match="num_learners"):
            learner_keys(0, n)
        with pytest.raises(ParamError, match="num_learners"):
            stack_for_learners(QRunnerParams(), n)
    with pytest.raises(ParamError, match="epsilon"):
        validate(ExplorationParams(init_value=1.5))
    with pytest.raises(ParamError, match="temperature"):
        validate(ExplorationParams(policy="boltzmann", end_value=0.0))
    with pytest.raises(ParamError, match="transition_steps"):
        validate(ScheduleParams(transition_steps=0.0))
    with pytest.raises(ParamError, match="num_envs"):
        validate(QRunnerParams(num_envs=0))


def test_runner_checks_env_compatibility():
    with pytest.raises(ParamError, match="start_difficulty"):  # LEM needs the env's knob
        make_qlearning_runner(ChainEnv(), chain_state_fn, QRunnerParams(
            num_states=N_CHAIN, num_actions=2, lem=LEMParams(enabled=True)))
    with pytest.raises(ParamError, match="num_actions"):
        make_qlearning_runner(ChainEnv(), chain_state_fn, QRunnerParams(
            num_states=N_CHAIN, num_actions=3, lem=LEMParams(enabled=False)))
