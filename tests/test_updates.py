"""The update rules (vbl.agents.updates) through the runner, with asynchronous macro actions:
each rule converges to its analytic / NumPy fixed point on a block chain whose macro
actions take several primitives, and async macro actions of one primitive give exactly
the runner without macro actions."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import vbl  # noqa: F401
from tests.test_qlearning import N_CHAIN, ChainEnv, chain_state_fn
from vbl.agents import (
    ExplorationParams,
    QRunnerParams,
    learner_keys,
    make_qlearning_runner,
    stack_for_learners,
)
from vbl.agents.lem import LEMParams
from vbl.agents.qlearning import rule_of
from vbl.agents.traces import TraceParams
from vbl.agents.updates import RULES
from vbl.envs.macro import MacroActionParams
from vbl.params import ParamError, validate

F32 = jnp.float32

# ---------------------------------------------------------------- the block chain SMDP
K, B, M = 3, 3, 6   # blocks, cells per block, cap on primitives per macro action
GAMMA = 0.9         # discount per primitive
FWD, BACK = 0, 1    # forward one cell / jump back to cell 0


@struct.dataclass
class BlockParams:
    max_steps: int = 400  # time limit, primitives (rarely reached)


@struct.dataclass
class BlockState:
    x: jax.Array  # () int32 cell
    t: jax.Array  # () int32 primitives in the episode


class BlockChain:
    """Cells 0..K*B-1 in K blocks; every episode starts at cell 0. Forward from the last
    cell scores (reward 1, terminal). The discrete state is the block, so a macro action
    (repeat until the block changes) forward takes B primitives, back from a block > 0 one
    primitive, back in block 0 (nothing changes) M primitives (the cap)."""

    num_actions = 2
    default_params = BlockParams()

    def reset(self, key, params):
        return jnp.array([0.0], F32), BlockState(x=jnp.int32(0), t=jnp.int32(0))

    def step(self, key, state, action, params):
        x = jnp.where(action == FWD, state.x + 1, 0).astype(jnp.int32)
        term = x >= K * B
        t = state.t + 1
        trunc = (t >= params.max_steps) & ~term
        done = term | trunc
        obs_r, st_r = self.reset(key, params)
        st = jax.tree.map(lambda a, b: jnp.where(done, a, b), st_r, BlockState(x=x, t=t))
        obs = jnp.where(done, obs_r, jnp.array([x], F32))
        return obs, st, term.astype(F32), term, trunc, {"success": term}


def block_of(obs):
    return (obs[..., 0] // B).astype(jnp.int32)


def smdp_model():
    """The SMDP the learner sees, written out by hand: per (block, action) the next block,
    the action's discounted reward, its primitives and whether it ends the episode."""
    nxt = np.zeros((K, 2), int)
    rew = np.zeros((K, 2))
    n = np.zeros((K, 2), int)
    term = np.zeros((K, 2), bool)
    for b in range(K):
        nxt[b, FWD], n[b, FWD] = b + 1, B
        if b == K - 1:
            nxt[b, FWD], term[b, FWD], rew[b, FWD] = 0, True, GAMMA ** (B - 1)
        nxt[b, BACK], n[b, BACK] = 0, (1 if b > 0 else M)
    return nxt, rew, n, term


def q_star_analytic():
    """Q*: forward all the way is optimal; from block b the goal is B(K-b) primitives away."""
    q = np.zeros((K, 2))
    v0 = GAMMA ** (B * K - 1)
    for b in range(K):
        q[b, FWD] = GAMMA ** (B * (K - b) - 1)
        q[b, BACK] = GAMMA * v0 if b > 0 else GAMMA ** M * v0
    return q


def q_epsilon_greedy(eps: float, iters: int = 2000):
    """NumPy fixed point of the on-policy rules under epsilon-greedy behaviour:
    Q(s, a) = R + gamma**n (1 - term) sum_b pi_eps(b | s') Q(s', b), pi_eps greedy in Q."""
    nxt, rew, n, term = smdp_model()
    q = np.zeros((K, 2))
    for _ in range(iters):
        pi = np.full((K, 2), eps / 2)
        pi[np.arange(K), np.argmax(q, axis=1)] += 1 - eps
        v = np.sum(pi * q, axis=1)
        q = rew + np.where(term, 0.0, GAMMA ** n * v[nxt])
    return q


def with_rule(rule: str, **params) -> QRunnerParams:
    """A learner with update rule ``rule`` (traces: lambda 0.9 over 8 decisions)."""
    return QRunnerParams(update=rule, trace=TraceParams(lam=0.9, length=8),
                         lem=LEMParams(enabled=False), **params)


def block_runner(rule: str, eps: float, envs: int = 32, steps: int = 250):
    params = with_rule(
        rule, num_states=K, num_actions=2, discount=GAMMA, learning_rate=0.2,
        exploration=ExplorationParams(schedule="constant", init_value=eps),
        macro=MacroActionParams(enabled=True, mode="async", max_repeats=M),
        num_envs=envs, chunk_steps=steps)
    return make_qlearning_runner(BlockChain(), block_of, params), params


def train_blocks(rule: str, eps: float, lrs, learners: int = 2):
    """Chunks with step sizes ``lrs`` (a decreasing schedule lets the estimates settle)."""
    runner, params = block_runner(rule, eps)
    bp = stack_for_learners(params, learners)
    ep = stack_for_learners(BlockParams(), learners)
    carry = runner.init_batch(learner_keys(0, learners), bp, ep)
    prims = acts = 0
    for lr in lrs:
        p = bp.replace(learning_rate=jnp.full((learners,), lr, F32))
        carry, m = runner.run_chunk_batch(carry, p, ep)
        prims += int(np.sum(m["primitives"]))
        acts += int(np.sum(m["actions"]))
    return np.asarray(carry.q), prims, acts


LRS = (0.2,) * 8 + (0.1,) * 8 + (0.05,) * 8 + (0.02,) * 8


@pytest.mark.slow
@pytest.mark.parametrize("rule", ["q_learning", "watkins"])
def test_off_policy_rules_with_async_macros_learn_q_star(rule):
    """Uniformly random behaviour: one-step Q-learning and Watkins' Q(lambda) (traces
    decaying by gamma**n * lambda per decision) reach the analytic Q* of the SMDP."""
    q, prims, acts = train_blocks(rule, 1.0, LRS)
    assert prims > 2 * acts  # the macro actions do last several primitives
    for i in range(q.shape[0]):
        np.testing.assert_allclose(q[i], q_star_analytic(), atol=0.01, err_msg=rule)


@pytest.mark.slow
@pytest.mark.parametrize("rule", ["sarsa", "monte_carlo"])
def test_on_policy_rules_with_async_macros_learn_the_epsilon_greedy_values(rule):
    """Epsilon-greedy behaviour (epsilon 0.3): Sarsa(lambda) (bootstrapping from the next
    decision's action, discount gamma**n) and Monte Carlo reach the values of the
    epsilon-greedy policy (NumPy fixed point), which differ from Q*."""
    want = q_epsilon_greedy(0.3)
    assert np.max(np.abs(want - q_star_analytic())) > 0.08
    q, _, _ = train_blocks(rule, 0.3, LRS + (0.01,) * 16)
    for i in range(q.shape[0]):  # Monte Carlo returns vary more: rarely taken actions
        np.testing.assert_allclose(q[i], want, atol=0.04, err_msg=rule)
        assert np.max(np.abs(q[i] - q_star_analytic())) > 0.04  # not Q*


# ------------------------------------- async macro actions of one primitive == no macros


def chain_runner(rule: str, macro: MacroActionParams):
    expl = ExplorationParams(schedule="linear", init_value=1.0, end_value=0.1,
                             transition_steps=100.0)
    params = with_rule(rule, num_states=N_CHAIN, num_actions=2, discount=0.9,
                       exploration=expl, macro=macro, num_envs=8, chunk_steps=120)
    return make_qlearning_runner(ChainEnv(), chain_state_fn, params), params


@pytest.mark.parametrize("rule", RULES)
def test_async_macros_of_one_primitive_equal_no_macros(rule):
    """max_repeats = 1: every action is one primitive and every env decides at every step,
    so the async runner draws and learns exactly as the runner without macro actions."""
    out = []
    for macro in (MacroActionParams(enabled=False),
                  MacroActionParams(enabled=True, mode="async", max_repeats=1)):
        runner, params = chain_runner(rule, macro)
        bp = stack_for_learners(params, 2)
        ep = stack_for_learners(ChainEnv.default_params, 2)
        carry, m = runner.run_chunk_batch(runner.init_batch(learner_keys(5, 2), bp, ep), bp, ep)
        out.append((np.asarray(carry.q), {k: np.asarray(v) for k, v in m.items()}))
    (q_plain, m_plain), (q_async, m_async) = out
    assert m_plain["episodes"].sum() > 10
    np.testing.assert_array_equal(q_async, q_plain)
    for k in ("episodes", "successes", "primitives", "actions", "td_abs"):
        np.testing.assert_array_equal(m_async[k], m_plain[k], err_msg=k)
    assert np.any(q_plain != 0.0)


def test_one_field_chooses_the_rule():
    """``update`` names the rule."""
    for rule in RULES:
        assert rule_of(QRunnerParams(update=rule)).name == rule
    with pytest.raises(ParamError):
        validate(QRunnerParams(update="tree_backup"))


def test_monte_carlo_rejects_bootstrapped_truncation():
    runner_params = QRunnerParams(num_states=N_CHAIN, num_actions=2, update="monte_carlo",
                                  truncation="bootstrap", lem=LEMParams(enabled=False))
    with pytest.raises(ParamError, match="bootstrap"):
        make_qlearning_runner(ChainEnv(), chain_state_fn, runner_params)
