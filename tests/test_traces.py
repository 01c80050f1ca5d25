"""Truncated eligibility traces (vbl.agents.traces): against a NumPy loop reference, lambda = 0
equals the one-step update exactly, convergence on the chain, an aliased toy POMDP, errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct
from reference.qlearning_np import trace_step_loop, value_iteration

import vbl  # noqa: F401
from tests.test_qlearning import N_CHAIN, ChainEnv, chain_state_fn, chain_tables
from vbl.agents import (
    ExplorationParams,
    QRunnerParams,
    learner_keys,
    make_qlearning_runner,
    q_update,
    stack_for_learners,
)
from vbl.agents.lem import LEMParams
from vbl.agents.traces import _BLOCK, TRACE_KINDS, TraceParams, trace_init, trace_update
from vbl.envs.macro import MacroActionParams
from vbl.params import ParamError, validate

S, A, E, T = 6, 3, 5, 40


def random_trajectory(seed: int):
    """E coherent env trajectories of T steps on a random S-state MDP (auto-reset), with
    terminal and truncated ends, 1-3 primitives per action and next actions for Sarsa."""
    rng = np.random.default_rng(seed)
    s = np.zeros((T, E), np.int32)
    a = rng.integers(0, A, (T + 1, E)).astype(np.int32)
    r = rng.normal(size=(T, E)).astype(np.float32)
    term = rng.random((T, E)) < 0.08
    trunc = (rng.random((T, E)) < 0.05) & ~term
    n = rng.integers(1, 4, (T, E)).astype(np.int32)
    s_next = np.zeros((T, E), np.int32)
    cur = rng.integers(0, S, E)
    for t in range(T):
        s[t] = cur
        s_next[t] = rng.integers(0, S, E)  # next state (after an end: the next start)
        cur = s_next[t]
    return dict(s=s, a=a[:T], a_next=a[1:], r=r, term=term, trunc=trunc, n=n, s_next=s_next)


def run_jax(q0, traj, lr, gamma, lam, length, kind, rule):
    def body(carry, x):
        q, tr = carry
        q, delta, tr = trace_update(q, tr, x["s"], x["a"], x["r"], x["s_next"], x["term"],
                                    x["term"] | x["trunc"], lr, gamma, lam, kind=kind,
                                    duplicates=rule, weight=~x["trunc"],
                                    num_primitives=x["n"], a_boot=x["a_next"],
                                    advance=x.get("advance"))
        return (q, tr), q

    xs = {k: jnp.asarray(v) for k, v in traj.items()}
    return jax.lax.scan(body, (jnp.asarray(q0, jnp.float32), trace_init(E, length)), xs)[1]


def run_np(q0, traj, lr, gamma, lam, length, kind, rule):
    q = np.array(q0, np.float64)
    windows = [[] for _ in range(E)]
    out = []
    for t in range(T):
        q = trace_step_loop(q, windows, traj["s"][t], traj["a"][t], traj["r"][t],
                            traj["s_next"][t], traj["term"][t],
                            traj["term"][t] | traj["trunc"][t], lr, gamma, lam, length,
                            kind=kind, rule=rule, weight=~traj["trunc"][t],
                            num_primitives=traj["n"][t], a_boot=traj["a_next"][t],
                            advance=traj["advance"][t] if "advance" in traj else None)
        out.append(q.copy())
    return np.stack(out)


@pytest.mark.parametrize("kind", TRACE_KINDS)
@pytest.mark.parametrize("rule", ["mean", "sum"])
def test_matches_numpy_loop_reference(kind, rule):
    traj = random_trajectory(1)
    # few states: pairs repeat within and across windows (the duplicate rule matters)
    q0 = np.random.default_rng(2).normal(size=(S, A)).astype(np.float32)
    for lam, length in ((0.8, 3), (1.0, 6), (0.5, 1)):
        got = jax.jit(run_jax, static_argnums=(5, 6, 7))(q0, traj, 0.3, 0.9, lam, length,
                                                         kind, rule)
        want = run_np(q0, traj, 0.3, 0.9, lam, length, kind, rule)
        np.testing.assert_allclose(np.asarray(got), want, rtol=1e-4, atol=1e-4,
                                   err_msg=f"{kind} {rule} lam={lam} L={length}")
    assert got.dtype == jnp.float32


@pytest.mark.parametrize("kind", ["peng", "naive", "watkins"])
def test_envs_whose_action_runs_on_keep_their_window(kind):
    """Asynchronous macro actions: at each step only the envs whose action ended
    (``advance``; always at an episode end) push a pair and update; the others' windows
    stay as they are. Against the NumPy loop that skips those envs."""
    traj = random_trajectory(5)
    rng = np.random.default_rng(6)
    traj["advance"] = (rng.random((T, E)) < 0.5) | traj["term"] | traj["trunc"]
    q0 = rng.normal(size=(S, A)).astype(np.float32)
    for rule in ("mean", "sum"):
        got = jax.jit(run_jax, static_argnums=(5, 6, 7))(q0, traj, 0.3, 0.9, 0.8, 4, kind,
                                                         rule)
        want = run_np(q0, traj, 0.3, 0.9, 0.8, 4, kind, rule)
        np.testing.assert_allclose(np.asarray(got), want, rtol=1e-4, atol=1e-4,
                                   err_msg=f"{kind} {rule}")
    # the mask matters: ignoring it gives another table
    plain = run_np(q0, {k: v for k, v in traj.items() if k != "advance"}, 0.3, 0.9, 0.8, 4,
                   kind, "mean")
    assert not np.allclose(plain[-1], run_np(q0, traj, 0.3, 0.9, 0.8, 4, kind, "mean")[-1])


@pytest.mark.parametrize("rule", ["mean", "sum"])
def test_learners_with_many_envs_match_the_numpy_loop_reference(rule):
    """More envs than one scatter block (``traces._BLOCK``), the update vmapped over three
    learners whose envs update at different rates (none, about a third, all): each learner's
    tables equal the NumPy loop's, the window's states and actions included."""
    n_env, n_t, length, lam = 2 * _BLOCK + 7, 12, 4, 0.8
    rng = np.random.default_rng(11)
    trajs = []
    for rate in (0.0, 0.3, 1.0):
        ends = rng.random((n_t, n_env)) < (0.1 if rate > 0 else 0.0)
        trajs.append(dict(s=rng.integers(0, S, (n_t, n_env)), a=rng.integers(0, A, (n_t, n_env)),
                          r=rng.normal(size=(n_t, n_env)).astype(np.float32),
                          s_next=rng.integers(0, S, (n_t, n_env)), term=ends,
                          n=rng.integers(1, 4, (n_t, n_env)),
                          advance=(rng.random((n_t, n_env)) < rate) | ends))
    q0 = rng.normal(size=(S, A)).astype(np.float32)

    def step(carry, x):
        q, tr = carry
        q, _, tr = trace_update(q, tr, x["s"], x["a"], x["r"], x["s_next"], x["term"],
                                x["term"], 0.3, 0.9, lam, kind="peng", duplicates=rule,
                                num_primitives=x["n"], advance=x["advance"])
        return (q, tr), q

    def run(q, xs):
        return jax.lax.scan(step, (q, trace_init(n_env, length)), xs)

    xs = {k: jnp.asarray(np.stack([t[k] for t in trajs], axis=1)) for k in trajs[0]}
    (_, tr), got = jax.jit(jax.vmap(run, in_axes=(None, 1)))(jnp.asarray(q0), xs)
    for i, t in enumerate(trajs):
        q, windows = np.array(q0, np.float64), [[] for _ in range(n_env)]
        for k in range(n_t):
            q = trace_step_loop(q, windows, t["s"][k], t["a"][k], t["r"][k], t["s_next"][k],
                                t["term"][k], t["term"][k], 0.3, 0.9, lam, length,
                                kind="peng", rule=rule, num_primitives=t["n"][k],
                                advance=t["advance"][k])
            np.testing.assert_allclose(np.asarray(got[i, k]), q, rtol=1e-5, atol=1e-5,
                                       err_msg=f"learner {i} step {k}")
        for e, w in enumerate(windows):
            live = np.asarray(tr.e[i, e]) > 0
            assert int(live.sum()) == len(w)
            np.testing.assert_array_equal(np.asarray(tr.s[i, e])[live], [p[0] for p in w])
            np.testing.assert_array_equal(np.asarray(tr.a[i, e])[live], [p[1] for p in w])
    assert np.array_equal(np.asarray(got[0, -1]), q0)  # no env updated: the table as it was
    assert not np.allclose(np.asarray(got[2, -1]), q0)


@pytest.mark.parametrize("kind", ["peng", "naive", "watkins"])
@pytest.mark.parametrize("rule", ["mean", "sum"])
def test_lambda_zero_is_the_one_step_update_exactly(kind, rule):
    traj = random_trajectory(3)
    q0 = np.random.default_rng(4).normal(size=(S, A)).astype(np.float32)
    got = run_jax(q0, traj, 0.25, 0.9, 0.0, 4, kind, rule)
    q = jnp.asarray(q0)
    for t in range(T):
        q, _ = q_update(q, traj["s"][t], traj["a"][t], traj["r"][t], traj["s_next"][t],
                        traj["term"][t], 0.25, 0.9, duplicates=rule, weight=~traj["trunc"][t],
                        num_primitives=traj["n"][t])
        np.testing.assert_array_equal(np.asarray(got[t]), np.asarray(q))


def chain_params(update: str, trace: TraceParams, expl: ExplorationParams,
                 steps=200) -> QRunnerParams:
    return QRunnerParams(
        num_states=N_CHAIN, num_actions=2, update=update, exploration=expl, trace=trace,
        macro=MacroActionParams(enabled=False), lem=LEMParams(enabled=False),
        num_envs=16, chunk_steps=steps)


RANDOM = ExplorationParams(schedule="constant", init_value=1.0)


def test_runner_with_lambda_zero_equals_runner_without_traces():
    ep = ChainEnv.default_params
    qs = []
    for update, trace in (("q_learning", TraceParams()),
                          ("peng", TraceParams(lam=0.0, length=4))):
        p = chain_params(update, trace, ExplorationParams(), steps=100)
        runner = make_qlearning_runner(ChainEnv(), chain_state_fn, p)
        carry = jax.jit(runner.init)(jax.random.PRNGKey(0), p, ep)
        carry, m = jax.jit(runner.run_chunk)(carry, p, ep)
        qs.append((np.asarray(carry.q), np.asarray(m["td_abs"])))
    np.testing.assert_array_equal(qs[0][0], qs[1][0])
    np.testing.assert_array_equal(qs[0][1], qs[1][1])
    assert np.abs(qs[0][0]).max() > 0


def test_runner_converges_to_value_iteration_with_traces():
    """Watkins' Q(lambda) learns Q* under random behaviour (3 learners sweep lambda); Peng's
    Q(lambda) and Sarsa(lambda) under a greedy-in-the-limit policy reach V* and act optimally."""
    nxt, rew, term = chain_tables()
    gamma = 0.8
    vi = value_iteration(nxt, rew, term, gamma)[:N_CHAIN - 1]
    ep = stack_for_learners(ChainEnv.default_params, 3)
    lams = jnp.asarray([0.3, 0.7, 1.0], jnp.float32)
    glie = ExplorationParams(schedule="linear", init_value=1.0, end_value=0.0,
                             transition_steps=300)
    for kind, expl, full in (("watkins", RANDOM, True), ("peng", glie, False),
                             ("sarsa", glie, False)):
        p = chain_params(kind, TraceParams(length=6), expl).replace(discount=gamma)
        runner = make_qlearning_runner(ChainEnv(), chain_state_fn, p)
        bp = stack_for_learners(p, 3)
        bp = bp.replace(trace=bp.trace.replace(lam=lams))
        carry = runner.init_batch(learner_keys(0, 3), bp, ep)
        for _ in range(3):
            carry, _ = runner.run_chunk_batch(carry, bp, ep)
        q = np.asarray(carry.q)[:, :N_CHAIN - 1]
        if full:
            np.testing.assert_allclose(q, np.broadcast_to(vi, q.shape), atol=1e-4)
        else:
            np.testing.assert_allclose(q.max(-1), np.broadcast_to(vi.max(-1), q.shape[:2]),
                                       atol=1e-3, err_msg=kind)
            assert np.all(q.argmax(-1) == 1), kind  # right everywhere


# ------------------------------------------------------------------ an aliased toy POMDP


@struct.dataclass
class ForkParams:
    max_steps: int = 10


@struct.dataclass
class ForkState:
    p: jax.Array  # () int32: 0 start, 1 left room, 2 right room
    t: jax.Array


class AliasedFork:
    """From the start (p = 0) action 0 leads to room 1, action 1 to room 2; in a room any
    action ends the episode, scoring 1 in room 2 and 0 in room 1. Both rooms look alike
    (one observed state), so one-step targets of both start actions are the same
    ``discount * max Q[room]``: one-step Q-learning cannot tell the start actions apart,
    while multi-step returns carry the room's reward back to the action that chose it."""

    num_actions = 2
    default_params = ForkParams()

    def reset(self, key, params):
        return jnp.zeros((1,), jnp.float32), ForkState(p=jnp.int32(0), t=jnp.int32(0))

    def step(self, key, state, action, params):
        in_room = state.p > 0
        p2 = jnp.where(in_room, state.p, 1 + action).astype(jnp.int32)
        r = (in_room & (state.p == 2)).astype(jnp.float32)
        term = in_room
        t = state.t + 1
        trunc = (t >= params.max_steps) & ~term
        done = term | trunc
        obs0, st0 = self.reset(key, params)
        st = jax.tree.map(lambda a, b: jnp.where(done, a, b), st0, ForkState(p=p2, t=t))
        obs = jnp.where(done, obs0, jnp.asarray([p2], jnp.float32))
        return obs, st, r, term, trunc, {"success": r > 0}


def fork_state(obs):
    return jnp.minimum(obs[..., 0], 1.0).astype(jnp.int32)  # rooms 1 and 2 aliased


@pytest.mark.parametrize("kind", ["peng", "sarsa"])
def test_multi_step_returns_solve_an_aliased_fork(kind):
    """lambda = 0: the start actions' values agree (no preference, greedy success about
    1/2); lambda 0.9 and 1: the right room's action is worth about discount * 1 more, and the
    greedy policy always scores."""
    expl = ExplorationParams(schedule="constant", init_value=0.5)
    p = QRunnerParams(
        num_states=2, num_actions=2, discount=0.9, exploration=expl, update=kind,
        trace=TraceParams(length=2),
        macro=MacroActionParams(enabled=False), lem=LEMParams(enabled=False),
        num_envs=16, chunk_steps=300)
    runner = make_qlearning_runner(AliasedFork(), fork_state, p)
    bp = stack_for_learners(p, 3)
    bp = bp.replace(trace=bp.trace.replace(lam=jnp.asarray([0.0, 0.9, 1.0], jnp.float32)))
    ep = stack_for_learners(AliasedFork.default_params, 3)
    carry, _ = runner.run_chunk_batch(runner.init_batch(learner_keys(0, 3), bp, ep), bp, ep)
    gap = np.asarray(carry.q[:, 0, 1] - carry.q[:, 0, 0])
    assert abs(gap[0]) < 0.05, gap           # one-step: the aliased room hides the reward
    assert np.all(gap[1:] > 0.6), gap         # about 0.9 * (1 - 0) (lambda 1), less at 0.9
    res = runner.evaluate_batch(learner_keys(1, 3), carry.q, bp, ep, 4)
    np.testing.assert_allclose(np.asarray(res["success_rate"][1:]), 1.0)


def test_traces_error_for_bad_parameters():
    for bad in (dict(lam=-0.1), dict(lam=1.5), dict(length=0)):
        with pytest.raises(ParamError):
            validate(QRunnerParams(update="peng", trace=TraceParams(**bad)))
    with pytest.raises(ParamError):
        validate(QRunnerParams(update="tree_backup"))
    with pytest.raises(ParamError):
        trace_init(4, 0)
    q = jnp.zeros((3, 2), jnp.float32)
    z = jnp.zeros((2,), jnp.int32)
    with pytest.raises(ParamError, match="lambda"):
        trace_update(q, trace_init(2, 2), z, z, z, z, z > 0, z > 0, 0.1, 0.9, 1.2)
    with pytest.raises(ParamError, match="a_boot"):
        trace_update(q, trace_init(2, 2), z, z, z, z, z > 0, z > 0, 0.1, 0.9, 0.5,
                     kind="sarsa")
