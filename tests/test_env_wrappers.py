"""vbl.envs.wrappers on a toy env: the history rule and the state vector against a NumPy loop
over the episode's raw samples, replay == stepping, first-episode counts, quantisation, and
the smoke checks (jit, vmap over learners' params, one trace, attribute forwarding, bad
input)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from vbl.envs.wrappers import (
    FirstEpisodeWrapper,
    HistoryFilterWrapper,
    HistoryParams,
    LinearFilter,
    QuantizeParams,
    QuantizeWrapper,
)
from vbl.params import ParamError

LAG, M = 3, 2
OUT = (3, 1)            # filter outputs of objects "a" (2 features) and "b" (1 feature)
TRACES = {"step": 0}    # Python-side count of traces of the toy env's step


@struct.dataclass
class ToyState:
    t: jax.Array      # () int32 steps in the episode
    obs: jax.Array    # (4,) float32


class ToyEnv:
    """obs (4,): object "a" = [0:2], "b" = [2:3], "flag" = [3:4]; command u = [a - 1, a / 2];
    an episode ends after 5 steps, or after 2 with action 0; success iff action 2."""

    num_actions = 3
    obs_slices = {"a": slice(0, 2), "b": slice(2, 3), "flag": slice(3, 4)}
    observation_shape = (4,)
    default_params = None

    def reset_state(self, key, params):
        """(state, eps) without the observation (the state holds it; no pixel noise)."""
        obs = jax.random.normal(key, (4,), jnp.float32)
        return ToyState(jnp.int32(0), obs), None

    def get_obs(self, state, params, eps):
        return state.obs

    def reset(self, key, params):
        state, _ = self.reset_state(key, params)
        return state.obs, state

    def step_env(self, key, state, action, params):
        """One step without the auto-reset."""
        TRACES["step"] += 1
        a = jnp.asarray(action, jnp.float32)
        t = state.t + 1
        term = (t >= 5) | ((t >= 2) & (action == 0))
        obs = state.obs + 0.3 * a + 0.1 * jax.random.normal(key, (4,), jnp.float32)
        info = {"u": jnp.stack([a - 1.0, 0.5 * a]), "success": action == 2}
        return obs, ToyState(t, obs), a, term, jnp.bool_(False), info

    def step(self, key, state, action, params):
        obs, st, r, term, trunc, info = self.step_env(key, state, action, params)
        obs = jnp.where(term, jax.random.normal(jax.random.fold_in(key, 1), (4,)), obs)
        return obs, ToyState(jnp.where(term, 0, st.t), obs), r, term, trunc, info


def toy_filters(seed: int) -> tuple:
    rng = np.random.default_rng(seed)
    f = lambda k, q: LinearFilter(  # noqa: E731
        Uu=jnp.asarray(rng.normal(size=(k, LAG, M)), jnp.float32),
        Uy=jnp.asarray(rng.normal(size=(k, LAG, q)), jnp.float32),
        u_mean=jnp.asarray(rng.normal(size=M), jnp.float32),
        u_scale=jnp.asarray(rng.uniform(0.5, 2, M), jnp.float32),
        y_mean=jnp.asarray(rng.normal(size=q), jnp.float32),
        y_scale=jnp.asarray(rng.uniform(0.5, 2, q), jnp.float32))
    return (f(OUT[0], 2), f(OUT[1], 1))


def run(env, params, actions, key=0):
    """Step ``env`` with ``actions``; returns per step (the output before the action, the
    state before it) and the raw toy env's samples (obs y(t), u(t), start, success, done)."""
    keys = jax.random.split(jax.random.PRNGKey(key), len(actions) + 1)
    x, st = env.reset(keys[0], params)
    raw_obs, raw_st = ToyEnv().reset(keys[0], None)
    outs, states, raw, start = [], [], [], True
    step, raw_step = jax.jit(env.step), jax.jit(ToyEnv().step)
    for k, a in zip(keys[1:], actions, strict=True):
        outs.append(x)
        states.append(st)
        x, st, _, term, trunc, _ = step(k, st, jnp.int32(a), params)
        obs2, raw_st, _, rterm, _, info = raw_step(k, raw_st, jnp.int32(a), None)
        raw.append((np.asarray(raw_obs, float), np.asarray(info["u"], float), start,
                    bool(info["success"]), bool(rterm)))
        raw_obs, start = obs2, bool(rterm)
    return outs, states, raw


def reference_states(raw, filters, kind, use_filter=True, extra=True):
    """State vectors from the raw samples by index arithmetic (float64): at t, object rows
    j = 0 .. LAG-1 hold y(t-j) and u(t-j) of the same episode; before its start y is its
    first observation and u = 0 (at rest); u(t) (not chosen yet) is at its mean."""
    out, ep0 = [], 0
    for t, (_, _, start, _, _) in enumerate(raw):
        ep0 = t if start else ep0
        blocks = []
        for g, (sl, k) in enumerate(zip((slice(0, 2), slice(2, 3)), OUT, strict=True)):
            cur = raw[t][0][sl]
            if kind == "current":
                blocks.append(cur)
                continue
            f = jax.tree.map(lambda a: np.asarray(a, float), filters[g])
            mu = np.zeros(k)
            for j in range(LAG):
                y = raw[max(t - j, ep0)][0][sl]
                un = np.zeros(M) if j == 0 else (
                    (raw[t - j][1] if t - j >= ep0 else np.zeros(M)) - f.u_mean) / f.u_scale
                mu += f.Uu[:, j] @ un + f.Uy[:, j] @ ((y - f.y_mean) / f.y_scale)
            if kind == "cva":
                blocks.append(mu)
            else:
                size = max(k, len(cur))
                v = mu if use_filter else cur
                blocks.append(np.pad(v, (0, size - len(v))))
        out.append(np.concatenate(blocks + ([raw[t][0][3:4]] if extra else [])))
    return np.asarray(out)


ACTIONS = [1, 2, 2, 1, 0, 0, 1, 1, 2, 2, 2, 2, 1, 0, 1, 0, 0, 2, 1, 1]


@pytest.mark.parametrize("kind, use_filter", [("cva", True), ("current", True),
                                              ("select", True), ("select", False)])
def test_state_vector_and_replay_match_a_numpy_loop(kind, use_filter):
    env = HistoryFilterWrapper(ToyEnv(), ("a", "b"), LAG, M, OUT, kind, ("flag",))
    filters = toy_filters(1)
    p = HistoryParams(None, filters if kind != "current" else (), jnp.bool_(use_filter))
    outs, _, raw = run(env, p, ACTIONS)
    assert sum(r[2] for r in raw) >= 4                       # several episodes
    ref = reference_states(raw, filters, kind, use_filter)
    assert ref.shape[1] == sum(env.block_dims())
    np.testing.assert_allclose(np.asarray(outs), ref, rtol=1e-5, atol=1e-5)
    # the quantiser's training states: replay of the recorded run, the same rule
    xs = env.replay(jnp.asarray([r[0] for r in raw], jnp.float32),
                    jnp.asarray([r[1] for r in raw], jnp.float32),
                    jnp.asarray([r[2] for r in raw]), p)
    np.testing.assert_allclose(np.asarray(xs), ref, rtol=1e-5, atol=1e-5)


def test_ppo_cva_input_follows_the_same_history_rule():
    """vbl.agents.ppo_inputs.InputEnv's 'cva' input (step_env, no auto-reset) gives the
    state vectors of the NumPy loop over one long episode."""
    from vbl.agents.cva_state import CVAStateParams
    from vbl.agents.ppo_inputs import InputEnv, InputParams
    from vbl.sysid.params import CVAParams

    p = CVAStateParams(objects=("a", "b"), n_used_objects=OUT,
                       ident=CVAParams(lag=0, lag_max=LAG, lag_rule="paper"))
    ienv = InputEnv(ToyEnv(), "cva", cva=p, m=M)
    filters = toy_filters(4)
    params = InputParams(None, filters)
    keys = jax.random.split(jax.random.PRNGKey(7), len(ACTIONS) + 1)
    x, st = ienv.reset(keys[0], params)
    raw_obs, raw_st = ToyEnv().reset(keys[0], None)
    outs, raw = [], []
    for k, a in zip(keys[1:], ACTIONS, strict=True):
        outs.append(x)
        x, st, *_ = ienv.step_env(k, st, jnp.int32(a), params)
        obs2, raw_st, *_, info = ToyEnv().step_env(k, raw_st, jnp.int32(a), None)
        raw.append((np.asarray(raw_obs, float), np.asarray(info["u"], float), not raw, False,
                    False))
        raw_obs = obs2
    ref = reference_states(raw, filters, "cva", extra=False)
    np.testing.assert_allclose(np.asarray(outs), ref, rtol=1e-5, atol=1e-5)


def test_first_episode_counts_and_quantisation():
    codes = jnp.asarray(np.random.default_rng(2).normal(size=(6, 5)), jnp.float32)
    nearest = lambda c, x: jnp.argmin(jnp.sum((c - x) ** 2, -1)).astype(jnp.int32)  # noqa: E731
    hist = HistoryFilterWrapper(ToyEnv(), ("a", "b"), LAG, M, OUT, "cva", ("flag",))
    env = QuantizeWrapper(FirstEpisodeWrapper(hist), nearest)
    p = QuantizeParams(HistoryParams(None, toy_filters(3)), codes)
    actions = [1, 1, 1, 1, 2, 0, 0, 2]     # episodes end at steps 5 (success) and 7 (not)
    outs, states, raw = run(env, p, actions + [1])
    done = np.cumsum([r[4] for r in raw[:-1]])
    for t in range(1, len(actions) + 1):                  # counters after t steps
        st = states[t]
        assert int(st.episodes) == done[t - 1]
        first_done = int(np.argmax([r[4] for r in raw])) if done[t - 1] else None
        want = raw[first_done][3] if first_done is not None else False
        assert bool(st.first_success) == want
    # index = nearest code of the state vector (NumPy), state passed through
    xs = np.asarray([np.asarray(o["state"], float) for o in outs])
    want = np.argmin(((np.asarray(codes, float)[None] - xs[:, None]) ** 2).sum(-1), axis=1)
    np.testing.assert_array_equal([int(o["index"]) for o in outs], want)
    assert int(states[-1].episodes) == 2 and bool(states[-1].first_success)
    assert isinstance(states[1].inner.hist_u, tuple)      # EpisodeCounts(HistoryState(...))


def test_jit_vmap_over_learners_one_trace_and_forwarding():
    hist = HistoryFilterWrapper(ToyEnv(), ("a", "b"), LAG, M, OUT, "select", ("flag",))
    env = FirstEpisodeWrapper(hist)
    assert env.num_actions == 3 and env.obs_slices is ToyEnv.obs_slices
    assert isinstance(env.unwrapped, ToyEnv) and env.block_dims() == (3, 1, 1)
    batch = jax.tree.map(lambda *a: jnp.stack(a), *[toy_filters(s) for s in range(4)])
    params = HistoryParams(None, batch, jnp.asarray([True, False, True, False]))
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    x, st = jax.vmap(env.reset)(keys, params)
    assert x.shape == (4, 5) and x.dtype == jnp.float32
    step = jax.jit(jax.vmap(env.step))
    TRACES["step"] = 0
    for a in (0, 1, 2):
        x, st, r, term, trunc, info = step(keys, st, jnp.full(4, a, jnp.int32), params)
    assert TRACES["step"] == 1 and st.episodes.dtype == jnp.int32
    # learner 1 (current features) sees its raw features, padded
    np.testing.assert_array_equal(np.asarray(x[1, 3:]), np.asarray(st.inner.inner.obs[1, 2:]))


def test_bad_input():
    with pytest.raises(ParamError, match="obs_slices"):
        HistoryFilterWrapper(ToyEnv(), ("a", "ball"), LAG, M, OUT)
    with pytest.raises(ParamError, match="kind"):
        HistoryFilterWrapper(ToyEnv(), ("a", "b"), LAG, M, OUT, "history")
    with pytest.raises(ParamError, match="one size per object"):
        HistoryFilterWrapper(ToyEnv(), ("a", "b"), LAG, M, (3,))
    with pytest.raises(AttributeError):
        _ = HistoryFilterWrapper(ToyEnv(), ("a", "b"), LAG, M, OUT).no_such_attribute
