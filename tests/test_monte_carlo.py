"""Monte Carlo updates of the Q-learning runner (vbl.agents.monte_carlo).

Truths: hand returns of a few logged decisions; on the 5-state chain under the uniformly
random policy (epsilon 1), every-visit Monte Carlo estimates Q^pi of that policy,
which a NumPy policy evaluation gives (Q(s, a) = 1 if a scores from s, else
gamma * mean_b Q(s', b): the return counts the scoring primitive as k = 0).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from tests.test_qlearning import N_CHAIN as N
from tests.test_qlearning import ChainEnv as Chain
from tests.test_qlearning import ChainParams
from tests.test_qlearning import chain_state_fn as state_fn
from vbl.agents import (
    ExplorationParams,
    QRunnerParams,
    learner_keys,
    make_qlearning_runner,
    stack_for_learners,
)
from vbl.agents.lem import LEMParams
from vbl.agents.monte_carlo import MC_PASS_ENTRIES, MCLog, mc_init, mc_log, mc_update
from vbl.envs.macro import MacroActionParams
from vbl.params import ParamError

LONG = ChainParams(max_steps=2000)   # truncation practically never happens


def random_policy_q(gamma: float) -> np.ndarray:
    """Q^pi of the uniformly random policy on the chain (policy evaluation)."""
    q = np.zeros((N, 2))
    for _ in range(2000):
        v = q.mean(axis=1)
        new = np.zeros_like(q)
        for s in range(N - 1):
            for a in range(2):
                s2 = min(s + 1, N - 1) if a == 1 else max(s - 1, 0)
                new[s, a] = 1.0 if s2 == N - 1 else gamma * v[s2]
        q = new
    return q


def test_mc_update_by_hand():
    """Env 0: decisions (s1, a0) at primitive 0 and (s1, a0) at 2, (s2, a1) at 3; scores on
    primitive 3 (gamma 0.5): returns 1/8, 1/2 (mean 5/16, two updates at lr 1/2: step 3/4)
    and 1. Env 1: one decision (s1, a0), trial still running: not learned from."""
    log = mc_init(2, 3, 4 * 2)
    t = jnp.asarray(True)
    for s, a, c, d1 in ((1, 0, 0, True), (1, 0, 2, False), (2, 1, 3, False)):
        log = mc_log(log, jnp.array([True, d1]), jnp.array([s, s]), jnp.array([a, a]),
                     jnp.array([c, c]))
    log = mc_log(log, jnp.array([True, False]), jnp.array([3, 3]), jnp.array([1, 1]),
                 jnp.array([4, 4]))                      # env 0's log is full: dropped
    np.testing.assert_array_equal(np.asarray(log.n), [3, 1])
    q0 = jnp.zeros((4, 2), jnp.float32).at[2, 1].set(0.2)
    q, log2, n = mc_update(q0, log, jnp.array([True, False]), jnp.array([True, True]),
                           jnp.array([3, 9]), 0.5, 0.5)
    want = np.asarray(q0).copy()
    want[1, 0] = 0.75 * (1 / 8 + 1 / 2) / 2
    want[2, 1] = 0.2 + 0.5 * (1.0 - 0.2)
    np.testing.assert_allclose(np.asarray(q), want, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(log2.n), [0, 1])
    assert float(n) == 3.0
    q_fail, _, _ = mc_update(q0, log, jnp.array([True, False]), jnp.array([False, False]),
                             jnp.array([3, 9]), 0.5, 0.5)
    assert float(q_fail[2, 1]) == pytest.approx(0.1) and float(q_fail[1, 0]) == 0.0
    q_skip, _, n_skip = mc_update(q0, log, jnp.array([True, False]), jnp.array([True, True]),
                                  jnp.array([3, 9]), 0.5, 0.5, weight=jnp.array([False, t]))
    np.testing.assert_array_equal(np.asarray(q_skip), np.asarray(q0))
    assert float(n_skip) == 0.0


def numpy_mc_update(q, s, a, clock, n, ended, scored, last, lr, gamma):
    """Every-visit batch update written plainly: loop over the ended envs' logged
    decisions, group by (state, action), move each towards its mean return."""
    q = q.astype(np.float64).copy()
    groups: dict = {}
    for e in np.flatnonzero(ended):
        for j in range(n[e]):
            ret = gamma ** (last[e] - clock[e, j]) if scored[e] else 0.0
            groups.setdefault((s[e, j], a[e, j]), []).append(ret)
    for (si, ai), rets in groups.items():
        q[si, ai] += (1 - (1 - lr) ** len(rets)) * (np.mean(rets) - q[si, ai])
    return q


def test_mc_update_matches_a_numpy_reference_with_shared_keys():
    """64 envs x 32 decisions over a 6 x 3 table (every key repeats within and across
    envs), a third of the envs ended, half of those scored."""
    rng = np.random.default_rng(3)
    n_env, length, n_s, n_a = 64, 32, 6, 3
    s, a = rng.integers(0, n_s, (n_env, length)), rng.integers(0, n_a, (n_env, length))
    clock = np.sort(rng.integers(0, 40, (n_env, length)), axis=1)
    n = rng.integers(0, length + 1, n_env)
    ended, scored = rng.random(n_env) < 0.33, rng.random(n_env) < 0.5
    last = np.full(n_env, 45)
    q0 = rng.random((n_s, n_a)).astype(np.float32)
    log = mc_init(n_env, length, n_s * n_a).replace(s=jnp.asarray(s, jnp.int32),
                                         a=jnp.asarray(a, jnp.int32),
                                         clock=jnp.asarray(clock, jnp.int32),
                                         n=jnp.asarray(n, jnp.int32))
    q, log2, used = mc_update(jnp.asarray(q0), log, jnp.asarray(ended), jnp.asarray(scored),
                              jnp.asarray(last, jnp.int32), 0.3, 0.9)
    want = numpy_mc_update(q0, s, a, clock, n, ended, scored, last, 0.3, 0.9)
    np.testing.assert_allclose(np.asarray(q), want, rtol=2e-6, atol=1e-7)
    assert float(used) == n[ended].sum()
    np.testing.assert_array_equal(np.asarray(log2.n), np.where(ended, 0, n))



def test_mc_update_vmapped_over_learners_that_need_different_numbers_of_passes():
    """Three learners in one vmapped update: no trial ended, one short trial, and most
    trials ended with long logs (more decisions than one pass of MC_PASS_ENTRIES reads);
    a masked trial (weight False) teaches nothing. Each equals the NumPy reference, the
    work table is all zeros after it, and a second update with the returned log (the same
    decisions logged again) equals the reference applied twice: a table left with one
    update's sums would carry them into the next."""
    rng = np.random.default_rng(7)
    n_env, length, n_s, n_a = 64, 128, 5, 2
    s = rng.integers(0, n_s, (3, n_env, length))
    a = rng.integers(0, n_a, (3, n_env, length))
    clock = np.sort(rng.integers(0, 200, (3, n_env, length)), axis=2)
    n = rng.integers(0, length + 1, (3, n_env))
    ended = np.zeros((3, n_env), bool)
    ended[1, 5] = True
    ended[2] = rng.random(n_env) < 0.8
    weight = np.ones((3, n_env), bool)
    weight[2, :4] = False
    assert (n[2] * (ended[2] & weight[2])).sum() > 3 * MC_PASS_ENTRIES
    scored = rng.random((3, n_env)) < 0.5
    last = np.full((3, n_env), 250)
    q0 = rng.random((3, n_s, n_a)).astype(np.float32)
    log = MCLog(s=jnp.asarray(s, jnp.int32), a=jnp.asarray(a, jnp.int32),
                clock=jnp.asarray(clock, jnp.int32), n=jnp.asarray(n, jnp.int32),
                sums=jnp.zeros((3, n_s * n_a + 1, 2), jnp.float32))
    update = jax.jit(jax.vmap(lambda q, lg, e, sc, la, w: mc_update(q, lg, e, sc, la, 0.2,
                                                                     0.9, w)))
    args = (jnp.asarray(ended), jnp.asarray(scored), jnp.asarray(last, jnp.int32),
            jnp.asarray(weight))
    q, log1, used = update(jnp.asarray(q0), log, *args)
    np.testing.assert_array_equal(np.asarray(log1.sums), 0.0)
    q2, log2, _ = update(q, log1.replace(n=jnp.asarray(n, jnp.int32)), *args)
    np.testing.assert_array_equal(np.asarray(log2.sums), 0.0)
    for i in range(3):
        use = ended[i] & weight[i]
        want = numpy_mc_update(q0[i], s[i], a[i], clock[i], n[i], use, scored[i], last[i],
                               0.2, 0.9)
        np.testing.assert_allclose(np.asarray(q[i]), want, rtol=2e-6, atol=1e-7)
        assert float(used[i]) == n[i][use].sum()
        want2 = numpy_mc_update(want, s[i], a[i], clock[i], n[i], use, scored[i], last[i],
                                0.2, 0.9)
        np.testing.assert_allclose(np.asarray(q2[i]), want2, rtol=4e-6, atol=2e-7)


def test_mc_update_refuses_a_work_table_of_another_q_table():
    """A log made for a 4 x 2 table cannot update a 4 x 3 one (its writes would drop)."""
    log = mc_init(1, 2, 4 * 2)
    with pytest.raises(ValueError, match=r"needs \(13, 2\)"):
        mc_update(jnp.zeros((4, 3)), log, jnp.array([True]), jnp.array([True]),
                  jnp.array([0]), 0.5, 0.5)


def _params(update="monte_carlo", lr=0.01, macro=False, **agent):
    expl = ExplorationParams(schedule="constant", init_value=1.0)
    return QRunnerParams(
        num_states=N, num_actions=2, exploration=expl, update=update, learning_rate=lr,
        discount=0.8, **agent,
        macro=MacroActionParams(enabled=macro, mode="async"), lem=LEMParams(enabled=False),
        num_envs=16, chunk_steps=200)


def test_runner_estimates_the_random_policys_values():
    params = _params()
    runner = make_qlearning_runner(Chain(), state_fn, params)
    bp = stack_for_learners(params, 2)
    ep = stack_for_learners(LONG, 2)
    carry = runner.init_batch(learner_keys(0, 2), bp, ep)
    for _ in range(5):
        carry, m = runner.run_chunk_batch(carry, bp, ep)
    want = random_policy_q(0.8)
    for i in range(2):
        np.testing.assert_allclose(np.asarray(carry.q[i, :N - 1]), want[:N - 1], atol=0.03)
    assert float(carry.q[0, N - 2, 1]) == pytest.approx(1.0, abs=1e-3)   # scores at once
    assert int(np.asarray(m["episodes"]).sum()) > 0


def test_async_macro_monte_carlo_learns_the_greedy_path():
    params = _params(lr=0.1, macro=True)
    runner = make_qlearning_runner(Chain(), state_fn, params)
    bp = stack_for_learners(params, 2)
    ep = stack_for_learners(LONG, 2)
    carry = runner.init_batch(learner_keys(3, 2), bp, ep)
    carry, _ = runner.run_chunk_batch(carry, bp, ep)
    assert np.all(np.asarray(carry.q[:, :N - 1, 1]) > np.asarray(carry.q[:, :N - 1, 0]))
    res = runner.evaluate_batch(learner_keys(4, 2), carry.q, bp, ep, 20)
    np.testing.assert_allclose(np.asarray(res["success_rate"]), 1.0)


def test_q_learning_default_unchanged_and_bad_combinations_are_clear_errors():
    assert QRunnerParams().update == "q_learning"
    with pytest.raises(ParamError, match="truncation"):
        make_qlearning_runner(Chain(), state_fn, _params(truncation="bootstrap"))
    with pytest.raises(ParamError, match="update"):
        make_qlearning_runner(Chain(), state_fn, _params(update="tree_backup"))
