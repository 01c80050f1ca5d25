"""Learning from Easy Missions: the difficulty rises when Q stops changing, and not before."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from vbl.agents import stack_for_learners
from vbl.agents.lem import LEMParams, lem_init, lem_update
from vbl.params import ParamError, validate

P = LEMParams(enabled=True, window=3, threshold=0.01, step=0.25)


def _drive(p, qs, episodes=None, successes=None):
    n = qs.shape[0]
    eps = jnp.zeros(n, jnp.float32) if episodes is None else jnp.asarray(episodes, jnp.float32)
    suc = jnp.zeros(n, jnp.float32) if successes is None else jnp.asarray(successes,
                                                                           jnp.float32)

    def body(st, x):
        q, e, s = x
        st = lem_update(st, q, p, e, s)
        return st, st.difficulty
    st, d = jax.lax.scan(body, lem_init(p, jnp.zeros(qs.shape[1:], jnp.float32)),
                         (qs, eps, suc))
    return d, st


def drive(p, qs):
    """Feed the tables qs (T, S, A) one per step; difficulty after each step (T,)."""
    d, st = _drive(p, qs)
    return np.asarray(d), st


def tables(values, shape=(4, 2)):
    return jnp.asarray(np.stack([np.full(shape, v, np.float32) for v in values]))


def test_raises_only_after_q_stops_changing():
    # Q changes at steps 1..6 (q_t = t), then stays at 6. Checks every 3 steps: the check at
    # step 9 sees no change since step 6 -> raise there, not earlier.
    vals = [1, 2, 3, 4, 5, 6] + [6] * 9
    d, st = drive(P, tables(vals))
    np.testing.assert_allclose(d[:8], 0.0)
    np.testing.assert_allclose(d[8:], 0.25)  # steps 9..15: one raise, no second (no learning)
    assert d.dtype == np.float32 and int(st.raises) == 1


def test_untouched_table_does_not_count_as_converged():
    d, st = drive(P, tables([0.0] * 12))
    np.testing.assert_allclose(d, 0.0)
    assert int(st.raises) == 0


def test_repeated_learning_raises_to_the_cap():
    # learn, settle, learn, settle ...: each settle raises; capped at max_difficulty 0.6
    p = P.replace(max_difficulty=0.6)
    vals = []
    for k in range(1, 6):
        vals += [float(k)] * 3 + [float(k)] * 3
    d, st = drive(p, tables(vals))
    assert d[-1] == pytest.approx(0.6)
    assert np.all(np.diff(d) >= 0) and int(st.raises) == 3  # 0.25, 0.5, 0.6


def test_success_gate():
    # Q settles after step 6 (as in the first test); windows end at steps 3, 6, 9, 12, 15.
    # Episodes: 2 per step; successes 1 per step until step 9, then 2 per step. With
    # success_level 0.75 the window ending at 9 (rate 0.5) may not raise, the one ending at
    # 12 (rate 1.0) does. No finished episode in a window: no raise.
    vals = [1, 2, 3, 4, 5, 6] + [6] * 9
    eps = [2.0] * 15
    suc = [1.0] * 9 + [2.0] * 6
    p = P.replace(success_level=0.75)
    d, st = _drive(p, tables(vals), eps, suc)
    d = np.asarray(d)
    np.testing.assert_allclose(d[:11], 0.0)
    np.testing.assert_allclose(d[11:], 0.25)
    assert int(st.raises) == 1
    # level 0.5 is met by the window ending at 9 (rate exactly 0.5): as without the gate
    d, _ = _drive(P.replace(success_level=0.5), tables(vals), eps, suc)
    np.testing.assert_allclose(np.asarray(d)[8:], 0.25)
    d, st = _drive(p, tables(vals), [0.0] * 15, [0.0] * 15)
    np.testing.assert_allclose(np.asarray(d), 0.0)
    assert int(st.raises) == 0


def test_max_versus_mean_statistic():
    # one of 8 entries keeps moving by 0.02 per step: max sees it, the mean (0.0025 per
    # step, 0.0075 per window) does not
    base = np.zeros((12, 4, 2), np.float32)
    base[:, 0, 0] = 1.0 + 0.02 * np.arange(12)
    d_max, _ = drive(P, jnp.asarray(base))
    d_mean, _ = drive(P.replace(statistic="mean"), jnp.asarray(base))
    np.testing.assert_allclose(d_max, 0.0)
    assert d_mean[-1] > 0.0


def test_success_only_gate():
    # statistic "none": Q keeps changing every step (never converged under max/mean), yet
    # each window whose training success reaches the level raises: windows end at steps
    # 3, 6, 9, 12; success 1/2 per step in the first two windows, 2/2 afterwards
    vals = [float(t) for t in range(12)]
    eps, suc = [2.0] * 12, [1.0] * 6 + [2.0] * 6
    p = P.replace(statistic="none", success_level=0.75)
    d, st = _drive(p, tables(vals), eps, suc)
    np.testing.assert_allclose(np.asarray(d), [0.0] * 8 + [0.25] * 3 + [0.5])
    assert int(st.raises) == 2
    d, _ = _drive(P.replace(success_level=0.75), tables(vals), eps, suc)
    np.testing.assert_allclose(np.asarray(d), 0.0)  # with the Q-change rule: never
    with pytest.raises(ParamError, match="success_level"):
        validate(P.replace(statistic="none"))


def test_backoff_lowers_after_failing_windows():
    # success-only gate at 0.75, back-off below 0.5, step 0.25, windows end at 3, 6, 9, 12,
    # 15: success 2/2, 2/2, 0/2, 1/2, 0/2 per step -> 0.25, 0.5, 0.25, 0.25 (0.5 is neither
    # < 0.5 nor >= 0.75), 0.0; never below initial_difficulty
    vals = [float(t) for t in range(15)]
    eps = [2.0] * 15
    suc = [2.0] * 6 + [0.0] * 3 + [1.0] * 3 + [0.0] * 3
    p = P.replace(statistic="none", success_level=0.75, backoff_level=0.5)
    d, st = _drive(p, tables(vals), eps, suc)
    np.testing.assert_allclose(np.asarray(d)[[2, 5, 8, 11, 14]], [0.25, 0.5, 0.25, 0.25, 0.0])
    assert int(st.raises) == 2
    d, _ = _drive(p.replace(initial_difficulty=0.25), tables(vals), eps, suc)
    assert np.asarray(d).min() >= 0.25  # floor: LEM off (initial = max) never moves
    with pytest.raises(ParamError, match="backoff_level"):
        validate(P.replace(backoff_level=0.5))  # success_level 0 < 0.5


def test_disabled_and_batched():
    d, _ = drive(P.replace(enabled=False), tables([1, 2, 3] + [3] * 9))
    np.testing.assert_allclose(d, 1.0)  # off: max_difficulty, fixed
    # two learners with different thresholds in one vmap: only the loose one raises
    qs = jnp.asarray(np.stack([np.full((4, 2), 1.0 + 0.001 * (t % 2), np.float32)
                               for t in range(9)]))
    ps = stack_for_learners(P, 2).replace(threshold=jnp.array([0.0005, 0.01], jnp.float32))
    d, _ = jax.vmap(_drive, in_axes=(0, None))(ps, qs)
    assert d[0, -1] == 0.0 and d[1, -1] > 0.0


@pytest.mark.parametrize("kw,match", [
    (dict(initial_difficulty=0.5, max_difficulty=0.3), "initial_difficulty"),
    (dict(step=0.0), "step"), (dict(window=0), "window"), (dict(threshold=0.0), "threshold"),
    (dict(initial_difficulty=1.5), "initial_difficulty"),
    (dict(success_level=1.5), "success_level")])
def test_bad_params(kw, match):
    with pytest.raises(ParamError, match=match):
        validate(LEMParams(**kw))
