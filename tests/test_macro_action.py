"""Macro actions (vbl.envs.macro.MacroWrapper) on a toy counter env: repeat until the
discrete state changes, cap, episode end inside the repeat, discounted reward, vmap over
environments, the async mode, stop rules, use inside the runner."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import vbl  # noqa: F401
from vbl.agents import (
    QRunnerParams,
    learner_keys,
    make_qlearning_runner,
    stack_for_learners,
)
from vbl.agents.lem import LEMParams
from vbl.envs.macro import (
    STOP_RULE_NAMES,
    MacroActionParams,
    MacroEnvParams,
    MacroState,
    MacroWrapper,
    RunningAction,
)
from vbl.params import ParamError, validate
from vbl.spaces.macro_action import STOP_RULES, grid_search_key, stop_key

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


class Outcome(struct.PyTreeNode):
    """One sync step of the wrapper, named (each (n,))."""

    obs: jax.Array
    state: MacroState
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    info: dict

    @property
    def num_primitives(self):
        return self.info["macro"]["num_primitives"]

    @property
    def next_state(self):
        return self.info["macro"]["next_state"]


def start_states(counters, t=0) -> MacroState:
    """Wrapper states (n,) at the given counters (no running action)."""
    counters = np.asarray(counters)
    n = len(counters)
    st = CounterState(c=jnp.asarray(counters, jnp.int32), t=jnp.full((n,), t, jnp.int32))
    index = jnp.asarray(counters // BLOCK, jnp.int32)
    return MacroState(inner=st, index=index, key=index,
                      running=RunningAction.none((n,)))


def wrapper_params(max_repeats=20, gamma=0.5, min_repeats=1) -> MacroEnvParams:
    return MacroEnvParams(inner=ENV.default_params, max_repeats=max_repeats,
                          min_repeats=min_repeats, discount=gamma)


def stepper(mode="sync", stop_on="state"):
    """jit(vmap(step)) of the counter env under the wrapper."""
    w = MacroWrapper(ENV, block_of, MacroActionParams(mode=mode, stop_on=stop_on),
                     stop_key(stop_on))
    return jax.jit(jax.vmap(w.step, in_axes=(0, 0, 0, None)))


SYNC = stepper()


def run(counters, actions, max_repeats=20, gamma=0.5, t=0, min_repeats=1):
    n = len(counters)
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    return Outcome(*SYNC(keys, start_states(counters, t), jnp.asarray(actions, jnp.int32),
                         wrapper_params(max_repeats, gamma, min_repeats)))


def test_repeat_until_state_changes_cap_and_episode_end():
    # counter 0 (+1): 0->3 in 3; counter 1: 2; counter 5 (-1): 5->2 in 3;
    # counter 4 (stay): never changes -> cap 7; counter 9 (+1): ends the episode in 1
    out = run([0, 1, 5, 4, 9], [0, 0, 2, 1, 0], max_repeats=7, gamma=0.5)
    np.testing.assert_array_equal(out.num_primitives, [3, 2, 3, 7, 1])
    assert out.num_primitives.dtype == jnp.int32 and out.reward.dtype == jnp.float32
    want_r = [sum(0.5 ** i for i in range(n)) for n in (3, 2, 3, 7, 1)]
    np.testing.assert_allclose(out.reward, want_r, rtol=1e-6)
    np.testing.assert_array_equal(out.state.inner.c, [3, 3, 2, 4, 0])  # last: auto-reset
    np.testing.assert_array_equal(out.next_state, [1, 1, 0, 1, 0])
    np.testing.assert_array_equal(out.terminated, [False, False, False, False, True])
    np.testing.assert_array_equal(out.info["success"], [False, False, False, False, True])
    np.testing.assert_array_equal(out.info["counter"], [3, 3, 2, 4, 10])  # pre-reset facts
    np.testing.assert_array_equal(out.state.inner.t, [3, 2, 3, 7, 0])
    np.testing.assert_array_equal(out.state.index, out.next_state)
    np.testing.assert_array_equal(out.info["macro"]["start"], [0, 0, 1, 1, 3])
    np.testing.assert_array_equal(out.info["macro"]["action"], [0, 0, 2, 1, 0])
    np.testing.assert_allclose(out.info["macro"]["reward"], want_r, rtol=1e-6)
    assert np.all(out.info["macro"]["decided"]) and np.all(out.info["macro"]["ended"])


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


def test_one_primitive_when_disabled():
    """macro.enabled=False: one step = one primitive (key as given), in either mode."""
    for mode in ("sync", "async"):
        w = MacroWrapper(ENV, block_of, MacroActionParams(enabled=False, mode=mode))
        out = Outcome(*jax.vmap(w.step, in_axes=(0, 0, 0, None))(
            jax.random.split(jax.random.PRNGKey(0), 3), start_states([0, 4, 9]),
            jnp.array([0, 1, 0], jnp.int32), wrapper_params(gamma=0.5)))
        np.testing.assert_array_equal(out.num_primitives, [1, 1, 1])
        np.testing.assert_array_equal(out.state.inner.c, [1, 4, 0])
        np.testing.assert_array_equal(out.next_state, [0, 1, 0])
        np.testing.assert_array_equal(out.terminated, [False, False, True])
        np.testing.assert_allclose(out.reward, [1.0, 1.0, 1.0])


def test_macro_params_validation():
    with pytest.raises(ParamError, match="max_repeats"):
        validate(MacroActionParams(max_repeats=0))
    with pytest.raises(ParamError, match="min_repeats"):
        validate(MacroActionParams(min_repeats=0))
    with pytest.raises(ParamError, match="stop_key"):
        MacroWrapper(ENV, block_of, MacroActionParams(stop_on="grid_search"))
    with pytest.raises(ParamError, match="stop_on"):
        stop_key("nope")
    assert tuple(STOP_RULES) == STOP_RULE_NAMES  # every name the params allow has a rule


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


def test_stop_on_grid_search_in_the_wrapper():
    # counter blocks 0, 1, 2 read as goal states 0, 1, 2 (one goal cell, orientations
    # left/front/right) of ball state 0: equal grid_search keys; block 3 is another cell.
    keys = jax.random.split(jax.random.PRNGKey(0), 1)
    out = {rule: Outcome(*stepper("sync", rule)(keys, start_states([0]), jnp.int32([0]),
                                                wrapper_params(20, 1.0)))
           for rule in ("state", "grid_search")}
    assert int(out["state"].num_primitives[0]) == 3     # 0 -> 3: block 1
    assert int(out["grid_search"].num_primitives[0]) == 9   # 0 -> 9: block 3
    assert int(out["grid_search"].next_state[0]) == 3


def test_async_gives_the_same_transitions_as_sync():
    """Async mode (one primitive per step, the env keeps its running action) ends each
    action where sync mode ends it, with the same start state, reward, length and next
    state."""
    counters = np.array([0, 4, 8, 2, 9, 5])
    actions = np.array([0, 1, 0, 2, 0, 0])
    cap, gamma = 5, 0.5
    ref = run(counters, actions, max_repeats=cap, gamma=gamma, t=0)
    n = len(counters)
    step, p = stepper("async"), wrapper_params(cap, gamma)
    st = start_states(counters)
    got = {k: np.full(n, -1.0) for k in ("start", "reward", "n", "next")}
    for i in range(cap):
        # the policy would choose something else: only the first step's choice may count
        chosen = jnp.asarray(actions if i == 0 else (actions + 1) % 3, jnp.int32)
        _, st, _, _, _, info = step(jnp.stack([jax.random.PRNGKey(i)] * n), st, chosen, p)
        mi = info["macro"]
        assert np.all(np.asarray(mi["decided"]) == (i == 0))
        np.testing.assert_array_equal(np.asarray(mi["action"]), actions)
        first = np.asarray(mi["ended"]) & (got["n"] < 0)
        for k, v in (("start", mi["start"]), ("reward", mi["reward"]),
                     ("n", mi["num_primitives"]), ("next", mi["next_state"])):
            got[k] = np.where(first, np.asarray(v, float), got[k])
        # an ended env would decide again: keep it frozen for this comparison
        frozen = jnp.asarray(got["n"] >= 0)
        st = st.replace(running=st.running.replace(
            count=jnp.where(frozen, 99, st.running.count)))
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
