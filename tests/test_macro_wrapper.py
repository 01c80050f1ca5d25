"""The macro-action wrapper around a plain env, outside any learner: a policy drives E
wrapped envs inside ``lax.scan`` (sync and async mode), and every step's outputs equal a
plain-Python loop over a NumPy copy of the env that implements the macro rules directly
(repeat until the discrete state changes, at least ``min_repeats``, at most
``max_repeats``, or the episode ends; discounted reward; the key of primitive i is
``fold_in(key, i)`` in sync mode and the step's key in async mode)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import vbl  # noqa: F401
from vbl.envs.macro import MacroActionParams, MacroEnvParams, MacroWrapper

GOAL, BLOCK, SLIP = 10, 3, 0.3    # counter goal, discrete state = counter // 3, P(slip)
MAX_STEPS = 14                     # episode time limit (primitives)
STEP_R, GOAL_R = -0.1, 2.0         # reward per primitive, extra reward at the goal
E, T = 5, 24                       # envs, scan steps
CAP, LEAST, GAMMA = 4, 2, 0.8      # max_repeats, min_repeats, discount


@struct.dataclass
class SlipState:
    c: jax.Array
    t: jax.Array


class SlipCounter:
    """Action 0: +1, 1: stay, 2: -1 (floor 0); with probability SLIP (uniform(key)) the
    move is lost. Auto-reset to 0 at the goal (terminated) or after MAX_STEPS (truncated)."""

    num_actions = 3

    def reset(self, key, params):
        return jnp.zeros((1,), jnp.float32), SlipState(jnp.int32(0), jnp.int32(0))

    def step(self, key, state, action, params):
        slip = jax.random.uniform(key) < SLIP
        delta = jnp.where(slip, 0, jnp.array([1, 0, -1], jnp.int32)[action])
        c, t = jnp.maximum(state.c + delta, 0), state.t + 1
        term = c >= GOAL
        trunc = (t >= MAX_STEPS) & ~term
        done = term | trunc
        st = SlipState(jnp.where(done, 0, c), jnp.where(done, 0, t))
        r = jnp.float32(STEP_R) + jnp.float32(GOAL_R) * term
        return st.c.astype(jnp.float32)[None], st, r, term, trunc, {"success": term}


def block_of(obs):
    return (obs[0] // BLOCK).astype(jnp.int32)


def policy(index, t):
    """Mostly +1; every third step an action that depends on the state."""
    return jnp.where(t % 3 == 2, (index + t) % 3, 0).astype(jnp.int32)


def scan_wrapper(mode: str, key):
    w = MacroWrapper(SlipCounter(), block_of, MacroActionParams(
        mode=mode, max_repeats=CAP, min_repeats=LEAST))
    p = MacroEnvParams(inner=None, max_repeats=jnp.int32(CAP), min_repeats=jnp.int32(LEAST),
                       discount=jnp.float32(GAMMA))
    k0, key = jax.random.split(key)
    _, st = jax.vmap(w.reset, in_axes=(0, None))(jax.random.split(k0, E), p)

    def body(carry, t):
        st, key = carry
        key, k = jax.random.split(key)
        obs, st, r, term, trunc, info = jax.vmap(w.step, in_axes=(0, 0, 0, None))(
            jax.random.split(k, E), st, policy(st.index, t), p)
        return (st, key), dict(obs=obs[:, 0], r=r, term=term, trunc=trunc, **info["macro"])

    return jax.jit(lambda key: jax.lax.scan(body, (st, key), jnp.arange(T))[1])(key)


# ------------------------------------------------------------------- NumPy reference


def np_primitive(c, t, a, key):
    """One primitive of SlipCounter in NumPy: (c, t, r, term, trunc) after auto-reset."""
    slip = float(jax.random.uniform(key)) < SLIP
    c = max(c + (0 if slip else (1, 0, -1)[a]), 0)
    t += 1
    term = c >= GOAL
    trunc = t >= MAX_STEPS and not term
    r = np.float32(STEP_R) + np.float32(GOAL_R) * np.float32(term)
    if term or trunc:
        c, t = 0, 0
    return c, t, r, term, trunc


def np_policy(s, t):
    return (s + t) % 3 if t % 3 == 2 else 0


def reference(mode: str, key) -> dict:
    """The trajectory of ``scan_wrapper`` by plain loops, each field (T, E)."""
    _, key = jax.random.split(key)
    step_keys = []
    for _ in range(T):
        key, k = jax.random.split(key)
        step_keys.append(jax.random.split(k, E))
    out = {f: np.zeros((T, E)) for f in ("obs", "r", "term", "trunc", "decided", "ended",
                                         "start", "action", "reward", "num_primitives",
                                         "next_state")}
    gamma = np.float32(GAMMA)
    for e in range(E):
        c, t_ep = 0, 0
        run = None  # async: [action, start, reward, weight, count]
        for t in range(T):
            s, k = c // BLOCK, step_keys[t][e]
            if mode == "sync":
                a, total, w, n = np_policy(s, t), np.float32(0), np.float32(1), 0
                while True:
                    c, t_ep, r, term, trunc = np_primitive(c, t_ep, a, jax.random.fold_in(k, n))
                    total, w, n = np.float32(total + w * r), np.float32(w * gamma), n + 1
                    if term or trunc or n >= CAP or (n >= LEAST and c // BLOCK != s):
                        break
                row = dict(r=total, decided=1, ended=1, start=s, action=a, reward=total,
                           num_primitives=n)
            else:
                decided = run is None
                if decided:
                    run = [np_policy(s, t), s, np.float32(0), np.float32(1), 0]
                a, start = run[0], run[1]
                c, t_ep, r, term, trunc = np_primitive(c, t_ep, a, k)
                run[2] = np.float32(run[2] + run[3] * r)
                run[3], run[4] = np.float32(run[3] * gamma), run[4] + 1
                ended = (term or trunc or run[4] >= CAP
                         or (run[4] >= LEAST and c // BLOCK != start))
                row = dict(r=r, decided=decided, ended=ended, start=start, action=a,
                           reward=run[2], num_primitives=run[4])
                if ended:
                    run = None
            row.update(obs=c, term=term, trunc=trunc, next_state=c // BLOCK)
            for f, v in row.items():
                out[f][t, e] = v
    return out


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_wrapper_in_scan_equals_a_numpy_loop(mode):
    key = jax.random.PRNGKey(7)
    got = {f: np.asarray(v, np.float64) for f, v in scan_wrapper(mode, key).items()}
    want = reference(mode, key)
    ended = want["ended"].astype(bool)
    for f in ("obs", "term", "trunc", "decided", "ended", "action", "next_state"):
        np.testing.assert_array_equal(got[f], want[f], err_msg=f)
    for f in ("start", "num_primitives"):  # the ended action's facts
        np.testing.assert_array_equal(got[f][ended], want[f][ended], err_msg=f)
    np.testing.assert_allclose(got["r"], want["r"], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(got["reward"][ended], want["reward"][ended], rtol=1e-6,
                               atol=1e-7)
    # the trajectory exercises every way an action ends
    assert want["term"].any() and want["trunc"].any()
    n = want["num_primitives"][ended]
    assert (n == CAP).any() and (n == LEAST).any() and (n < LEAST).any()
    if mode == "async":
        assert not want["decided"].all() and not want["ended"].all()
