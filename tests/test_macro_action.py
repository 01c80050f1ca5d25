"""Macro actions on a toy counter env: repeat until the discrete state changes, cap, episode
end inside the repeat, discounted reward, vmap over environments, use inside the runner."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import vbl  # noqa: F401  (x64 on, as in every vbl program)
from vbl.agents import (
    QRunnerParams,
    learner_keys,
    make_qlearning_runner,
    stack_for_learners,
)
from vbl.agents.lem import LEMParams
from vbl.params import ParamError, validate
from vbl.spaces.macro_action import MacroActionParams, make_macro_step

GOAL = 10   # the counter reaching 10 ends the episode with success
BLOCK = 3   # discrete state = counter // 3


@struct.dataclass
class CounterParams:
    max_steps: int = 50
    step_reward: float = 1.0   # reward of every primitive
    goal_reward: float = 0.0   # extra reward on reaching the goal


@struct.dataclass
class CounterState:
    c: jax.Array
    t: jax.Array


class CounterEnv:
    """Action 0: +1, action 1: stay, action 2: -1 (floor 0)."""

    num_actions = 3
    default_params = CounterParams()

    def reset(self, key, params):
        return jnp.array([0.0], jnp.float32), CounterState(c=jnp.int32(0), t=jnp.int32(0))

    def step(self, key, state, action, params):
        delta = jnp.array([1, 0, -1], jnp.int32)[action]
        c = jnp.maximum(state.c + delta, 0)
        t = state.t + 1
        term = c >= GOAL
        trunc = (t >= params.max_steps) & ~term
        done = term | trunc
        obs_r, st_r = self.reset(key, params)
        st = jax.tree.map(lambda a, b: jnp.where(done, a, b), st_r, CounterState(c=c, t=t))
        obs = jnp.where(done, obs_r, jnp.array([c], jnp.float32))
        r = (params.step_reward + params.goal_reward * term).astype(jnp.float32)
        return obs, st, r, term, trunc, {"success": term, "counter": c}


def block_of(obs):
    return (obs[..., 0] // BLOCK).astype(jnp.int32)


ENV = CounterEnv()
MACRO = jax.jit(jax.vmap(make_macro_step(ENV.step, block_of),
                         in_axes=(0, 0, 0, 0, None, None, None, None)))


def run(counters, actions, max_repeats=20, gamma=0.5, t=0, min_repeats=1):
    counters = np.asarray(counters)
    n = len(counters)
    st = CounterState(c=jnp.asarray(counters, jnp.int32), t=jnp.full((n,), t, jnp.int32))
    s0 = jnp.asarray(counters // BLOCK, jnp.int32)
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    return MACRO(keys, st, s0, jnp.asarray(actions, jnp.int32), ENV.default_params,
                 max_repeats, gamma, min_repeats)


def test_repeat_until_state_changes_cap_and_episode_end():
    # counter 0 (+1): 0->3 in 3; counter 1: 2; counter 5 (-1): 5->2 in 3;
    # counter 4 (stay): never changes -> cap 7; counter 9 (+1): ends the episode in 1
    out = run([0, 1, 5, 4, 9], [0, 0, 2, 1, 0], max_repeats=7, gamma=0.5)
    np.testing.assert_array_equal(out.num_primitives, [3, 2, 3, 7, 1])
    assert out.num_primitives.dtype == jnp.int32 and out.reward.dtype == jnp.float32
    want_r = [sum(0.5 ** i for i in range(n)) for n in (3, 2, 3, 7, 1)]
    np.testing.assert_allclose(out.reward, want_r, rtol=1e-6)
    np.testing.assert_array_equal(out.env_state.c, [3, 3, 2, 4, 0])  # last: auto-reset
    np.testing.assert_array_equal(out.next_state, [1, 1, 0, 1, 0])
    np.testing.assert_array_equal(out.terminated, [False, False, False, False, True])
    np.testing.assert_array_equal(out.info["success"], [False, False, False, False, True])
    np.testing.assert_array_equal(out.info["counter"], [3, 3, 2, 4, 10])  # pre-reset facts
    np.testing.assert_array_equal(out.env_state.t, [3, 2, 3, 7, 0])


def test_truncation_inside_the_repeat_and_traced_cap():
    out = run([4, 4], [1, 1], max_repeats=jnp.int32(30), gamma=1.0, t=45)  # limit at t=50
    np.testing.assert_array_equal(out.num_primitives, [5, 5])
    np.testing.assert_array_equal(out.truncated, [True, True])
    np.testing.assert_allclose(out.reward, [5.0, 5.0])
    # the cap is traced: a vmapped sweep over caps in one compiled function
    f = jax.jit(jax.vmap(lambda m: run([4], [1], max_repeats=m).num_primitives[0]))
    np.testing.assert_array_equal(f(jnp.array([1, 2, 9], jnp.int32)), [1, 2, 9])


def test_min_repeats():
    # counter 2 (+1) leaves block 0 after 1 primitive; with min 4 it runs 4 (2->6, block 2);
    # counter 5 (-1): 4 primitives end at 1 (block 0, changed); counter 4 (stay) hits cap 6;
    # counter 8 (+1) ends the episode after 2 primitives, before the minimum
    out = run([2, 5, 4, 8], [0, 2, 1, 0], max_repeats=6, gamma=1.0, min_repeats=4)
    np.testing.assert_array_equal(out.num_primitives, [4, 4, 6, 2])
    np.testing.assert_array_equal(out.next_state, [2, 0, 1, 0])
    np.testing.assert_array_equal(out.terminated, [False, False, False, True])
    # a minimum above the cap is capped: counter 4 (stay) with min 9, cap 3 -> 3
    np.testing.assert_array_equal(run([4], [1], max_repeats=3, min_repeats=9).num_primitives,
                                  [3])


def test_macro_params_validation():
    with pytest.raises(ParamError, match="max_repeats"):
        validate(MacroActionParams(max_repeats=0))
    with pytest.raises(ParamError, match="min_repeats"):
        validate(MacroActionParams(min_repeats=0))


def train_counter(mode: str, transition_steps: float, chunk_steps: int, trace=None):
    """One chunk of Q-learning on the blocks (state = counter // 3) with macro actions
    (``mode`` 'sync' or 'async', ``trace`` a trace rule or None for one-step updates),
    2 learners x 8 envs; returns (carry, metrics)."""
    from vbl.agents import ExplorationParams
    from vbl.agents.traces import TraceParams

    params = QRunnerParams(
        num_states=GOAL // BLOCK + 1, num_actions=3, discount=0.9,
        exploration=ExplorationParams(schedule="linear", init_value=1.0, end_value=0.0,
                                      transition_steps=transition_steps),
        update=trace or "q_learning", trace=TraceParams(lam=0.9, length=4),
        macro=MacroActionParams(enabled=True, max_repeats=5, mode=mode),
        lem=LEMParams(enabled=False), num_envs=8, chunk_steps=chunk_steps)
    runner = make_qlearning_runner(ENV, block_of, params)
    bp = stack_for_learners(params, 2)
    ep = stack_for_learners(CounterParams(step_reward=0.0, goal_reward=1.0), 2)
    carry = runner.init_batch(learner_keys(3, 2), bp, ep)
    return runner.run_chunk_batch(carry, bp, ep)


def test_runner_with_macro_actions_learns_the_counter():
    """Q-learning on the blocks (state = counter // 3) with macro actions reaches the goal."""
    carry, m = train_counter("sync", 60.0, 100)
    prim, act = np.asarray(m["primitives"]), np.asarray(m["actions"])
    assert np.all(prim >= act) and prim.sum() > act.sum()  # actions span several primitives
    # the learned greedy action in every non-terminal block is "+1"
    np.testing.assert_array_equal(np.argmax(np.asarray(carry.q)[:, :GOAL // BLOCK], -1), 0)
    # late in the chunk (epsilon 0) every finished episode succeeds in 4 macro actions
    late = slice(80, 100)
    assert np.all(np.asarray(m["successes"])[:, late] == np.asarray(m["episodes"])[:, late])


def test_grid_search_key_hand_built_states():
    from vbl.spaces.grid import NUM_GOAL_STATES as G
    from vbl.spaces.macro_action import grid_search_key

    def idx(ball, goal):
        return G * ball + goal

    # ball (centre, large) = 5; goal (centre, large, left/front/right) = 15, 16, 17
    keys = np.asarray(grid_search_key(jnp.array([idx(5, 15), idx(5, 16), idx(5, 17)])))
    assert len(set(keys.tolist())) == 1  # orientation ignored
    # a goal position or size change, or a ball change, still counts
    assert grid_search_key(idx(5, 16)) != grid_search_key(idx(5, 7))   # goal left third
    assert grid_search_key(idx(5, 16)) != grid_search_key(idx(5, 13))  # goal medium
    assert grid_search_key(idx(5, 16)) != grid_search_key(idx(4, 16))  # ball medium
    # goal lost left (27) = lost right (28) while the ball is visible, but != goal seen
    assert grid_search_key(idx(5, 27)) == grid_search_key(idx(5, 28))
    assert grid_search_key(idx(5, 27)) != grid_search_key(idx(5, 16))
    # ball lost: the goal is ignored; lost left (9) != lost right (10) != ball seen
    lost_left = np.asarray(grid_search_key(jnp.array([idx(9, g) for g in range(G)])))
    assert np.all(lost_left == lost_left[0])
    assert grid_search_key(idx(9, 3)) != grid_search_key(idx(10, 3))
    assert grid_search_key(idx(9, 3)) != grid_search_key(idx(2, 3))


def test_stop_on_grid_search_in_macro_step():
    from vbl.spaces.macro_action import macro_step

    # counter blocks 0, 1, 2 read as goal states 0, 1, 2 (one goal cell, orientations
    # left/front/right) of ball state 0: equal grid_search keys; block 3 is another cell.
    st = CounterState(c=jnp.int32(0), t=jnp.int32(0))
    out = {rule: macro_step(ENV.step, block_of, jax.random.PRNGKey(0), st, jnp.int32(0),
                            jnp.int32(0), ENV.default_params, 20, 1.0, stop_on=rule)
           for rule in ("state", "grid_search")}
    assert int(out["state"].num_primitives) == 3     # 0 -> 3: block 1
    assert int(out["grid_search"].num_primitives) == 9   # 0 -> 9: block 3
    assert int(out["grid_search"].next_state) == 3
    with pytest.raises(ValueError, match="stop_on"):
        macro_step(ENV.step, block_of, jax.random.PRNGKey(0), st, jnp.int32(0), jnp.int32(0),
                   ENV.default_params, 20, 1.0, stop_on="nope")


def test_async_macro_gives_the_same_transitions_as_macro_step():
    """Async mode (one primitive per call, the env keeps its running action) ends each action
    where macro_step ends it, with the same start state, reward, length and next state."""
    from vbl.spaces.macro_action import async_macro_advance, macro_carry_init

    counters = np.array([0, 4, 8, 2, 9, 5])
    actions = np.array([0, 1, 0, 2, 0, 0])
    cap, gamma = 5, 0.5
    ref = run(counters, actions, max_repeats=cap, gamma=gamma, t=0)
    n = len(counters)
    st = CounterState(c=jnp.asarray(counters, jnp.int32), t=jnp.zeros((n,), jnp.int32))
    s = jnp.asarray(counters // BLOCK, jnp.int32)
    carry = macro_carry_init(n)
    step = jax.vmap(ENV.step, in_axes=(None, 0, 0, None))
    got = {k: np.full(n, -1.0) for k in ("start", "reward", "n", "next")}
    for i in range(cap):
        def step_out(a, st=st, i=i):
            obs, st2, r, term, trunc, info = step(jax.random.PRNGKey(i), st, a,
                                                  ENV.default_params)
            return obs, st2, r, term, trunc, info, block_of(obs)
        # the policy would choose something else: only the first call's choice may count
        chosen = jnp.asarray(actions if i == 0 else (actions + 1) % 3, jnp.int32)
        out, ended, (start, act, rew, cnt, decided), carry = async_macro_advance(
            carry, s, chosen, step_out, cap, gamma)
        assert np.all(np.asarray(decided) == (i == 0))
        np.testing.assert_array_equal(np.asarray(act), actions)
        first = np.asarray(ended) & (got["n"] < 0)
        for k, v in (("start", start), ("reward", rew), ("n", cnt), ("next", out[6])):
            got[k] = np.where(first, np.asarray(v, float), got[k])
        st, s = out[1], out[6]
        # an ended env would decide again: keep it frozen for this comparison
        carry = carry.replace(count=jnp.where(jnp.asarray(got["n"] >= 0), 99, carry.count))
    np.testing.assert_array_equal(got["start"], counters // BLOCK)
    np.testing.assert_array_equal(got["n"], np.asarray(ref.num_primitives))
    np.testing.assert_allclose(got["reward"], np.asarray(ref.reward), rtol=1e-6)
    np.testing.assert_array_equal(got["next"], np.asarray(ref.next_state))


@pytest.mark.parametrize("trace", [None, "peng", "watkins"])
def test_runner_with_async_macro_actions_learns_the_counter(trace):
    """The same learning with async macro actions (runner steps = primitives), with
    one-step updates and with multi-step returns (each env's window advances only when
    its action ends)."""
    carry, m = train_counter("async", 200.0, 300, trace)
    prim, act = np.asarray(m["primitives"]), np.asarray(m["actions"])
    assert np.all(prim >= act) and prim.sum() > act.sum()
    np.testing.assert_array_equal(np.argmax(np.asarray(carry.q)[:, :GOAL // BLOCK], -1), 0)
    # greedy at the end: every finished episode succeeds in 10 primitives and 4 actions
    late = slice(250, 300)
    eps_, succ = np.asarray(m["episodes"])[:, late], np.asarray(m["successes"])[:, late]
    assert eps_.sum() > 0 and np.all(succ == eps_)
    done = eps_ > 0
    np.testing.assert_array_equal(prim[:, late][done], 10 * eps_[done])
    np.testing.assert_array_equal(act[:, late][done], 4 * eps_[done])
