"""The lag rule of Sec. 3.1.2 (vbl.sysid.lag_rule.select_lag) against the paper's procedure
written as a plain loop, on hand cases and random per-lag results; and the CVA learner's
identify_object picks the lag that rule gives on its own per-lag fits."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.sysid.lag_rule import select_lag


def paper_procedure(logdet, aic, stop):
    """Sec. 3.1.2 step by step for one data set: from l = 1, identify; (a) log det R < stop:
    stop with l; (b) else go on to l + 1 unless AIC did not decrease (then l - 1 is kept).
    A NaN marks a lag not identified: the procedure ends there with the last identified l."""
    for j in range(len(logdet)):
        if math.isnan(logdet[j]) or math.isnan(aic[j]):
            return max(j - 1, 0), False
        if logdet[j] < stop:
            return j, True
        if j > 0 and not aic[j] < aic[j - 1]:
            return j - 1, True
    return len(logdet) - 1, False


NAN = float("nan")
HAND = [
    # (logdet, aic, stop, expected index, decided)
    ([-0.001, 0.5, 0.2], [121.0, 100.0, 90.0], 0.0, 0, True),    # (a) at l = 1 (Table 1 goal)
    ([0.9, 0.232, 0.3], [200.0, 138.0, 150.0], 0.0, 1, True),    # (b) at l = 3: keep l = 2
    ([0.9, 0.5, -0.463], [200.0, 150.0, 79.0], 0.0, 2, True),    # (a) at l = 3
    ([0.9, -0.2, 0.1], [100.0, 120.0, 80.0], 0.0, 1, True),      # (a) and AIC worse at l = 2
    ([0.9, 0.5, 0.4], [100.0, 100.0, 80.0], 0.0, 0, True),       # AIC equal: not decreasing
    ([0.9, 0.5, 0.4], [100.0, 90.0, 80.0], 0.0, 2, False),       # lags run out: the last
    ([0.9, 0.5, NAN], [100.0, 90.0, NAN], 0.0, 1, False),        # not identified beyond l = 2
    ([0.9, NAN, -5.0], [100.0, NAN, 10.0], 0.0, 0, False),       # nothing after a gap counts
    ([NAN, NAN, NAN], [NAN, NAN, NAN], 0.0, 0, False),           # nothing identified
    ([0.9, 0.5, 0.4], [100.0, 90.0, 80.0], -100.0, 2, False),    # Table 2's stop: AIC only
    ([5.0], [10.0], 0.0, 0, False),                              # one lag
]


@pytest.mark.parametrize("logdet, aic, stop, index, decided", HAND)
def test_hand_cases(logdet, aic, stop, index, decided):
    assert paper_procedure(logdet, aic, stop) == (index, decided)
    j, d = select_lag(jnp.asarray(logdet), jnp.asarray(aic), stop)
    assert (int(j), bool(d)) == (index, decided)
    assert j.dtype == jnp.int32 and d.dtype == jnp.bool_


def random_cases(rng, shape, n_lags):
    """Per-lag results with ties, NaN tails and log dets around the stop."""
    logdet = rng.choice([-1.0, -0.5, 0.0, 0.5, 1.0, 2.0], size=shape + (n_lags,))
    aic = rng.choice([50.0, 80.0, 100.0, 120.0], size=shape + (n_lags,))
    cut = rng.integers(0, n_lags + 1, size=shape)                 # lags identified per set
    tail = np.arange(n_lags) >= cut[..., None]
    return np.where(tail, np.nan, logdet), np.where(tail, np.nan, aic)


def test_random_batches_jit_and_vmap_match_the_procedure():
    rng = np.random.default_rng(0)
    logdet, aic = random_cases(rng, (4, 250), 5)
    ref = np.array([[paper_procedure(a, b, 0.25) for a, b in zip(la, lb, strict=True)]
                    for la, lb in zip(logdet, aic, strict=True)])       # (4, 250, 2)
    j, d = jax.jit(select_lag)(logdet, aic, 0.25)                      # batch axes (4, 250)
    np.testing.assert_array_equal(np.asarray(j), ref[..., 0])
    np.testing.assert_array_equal(np.asarray(d), ref[..., 1].astype(bool))
    # vmapped over data sets and over the stop (traced)
    stops = jnp.asarray([-0.75, 0.25, 1.5])
    jv, dv = jax.vmap(select_lag, in_axes=(None, None, 0))(logdet[0], aic[0], stops)
    for s, stop in enumerate(np.asarray(stops)):
        ref = np.array([paper_procedure(a, b, stop) for a, b in zip(logdet[0], aic[0],
                                                                    strict=True)])
        np.testing.assert_array_equal(np.asarray(jv[s]), ref[:, 0])
        np.testing.assert_array_equal(np.asarray(dv[s]), ref[:, 1].astype(bool))
    # the disagreement case (a) with a worse AIC occurs in these data
    hit_and_worse = (logdet[..., 1:] < 0.25) & (aic[..., 1:] >= aic[..., :-1])
    assert hit_and_worse.any()


@pytest.fixture(scope="module")
def per_lag():
    """A second-order system driven by random inputs, 600 samples (u (N, 1), y (N, 2)), and
    fit_one's n*, log det R(n*), AIC(n*) (float32, as the learner keeps them) at l = 1..3
    (each fit one jitted program: op by op it takes half a minute)."""
    from vbl.sysid import fit_one, n_identifiable
    from vbl.sysid.params import CVAParams

    rng = np.random.default_rng(5)
    n_samp = 600
    u = rng.choice([-1.0, 1.0], size=(n_samp, 1))
    x, y = np.zeros(2), np.zeros((n_samp, 2))
    a = np.array([[0.9, 0.3], [-0.3, 0.8]])
    for t in range(n_samp):
        y[t] = x + 0.1 * rng.normal(size=2)
        x = a @ x + np.array([0.5, 0.2]) * u[t, 0]
    u, y = jnp.asarray(u, jnp.float32), jnp.asarray(y, jnp.float32)
    cva = CVAParams(lag=0, lag_max=3, lag_rule="paper")
    fits = []
    for lag in (1, 2, 3):
        k = cva.horizon_for(lag)
        fit = functools.partial(fit_one, params=cva, lag=lag, horizon=k,
                                n_cap=n_identifiable(lag, k, 1, 2))
        f = jax.jit(fit)(u, y)
        fits.append((int(f.n), float(np.float32(f.logdet[f.n])), float(np.float32(f.aic[f.n]))))
    return u, y, cva, fits


@pytest.fixture(scope="module")
def identify(per_lag):
    """identify_object on the module's data, jitted once with the stop traced (as the
    engine runs it: one program for every stop)."""
    from vbl.agents.cva_state import identify_object

    u, y, cva, _ = per_lag
    run = jax.jit(lambda u, y, stop: identify_object(u, y, cva.replace(logdet_stop=stop), 2))
    return lambda stop: run(u, y, stop)


@pytest.mark.parametrize("stop", [-100.0, 1e9, "between"])
def test_identify_object_takes_the_rules_lag(per_lag, identify, stop):
    """identify_object's lag, order, log det and AIC are those of the lag the procedure
    picks from fit_one's per-lag n*, log det R(n*) and AIC(n*)."""
    _, _, _, per = per_lag
    logdet = [p[1] for p in per]
    if stop == "between":   # (a) fires at the lag with the lowest log det beyond l = 1
        stop = float(np.nextafter(np.float32(min(logdet[1:])), np.float32(np.inf)))
    j, _ = paper_procedure(logdet, [p[2] for p in per], stop)
    mod = identify(stop)
    assert int(mod.lag) == j + 1 and int(mod.n) == per[j][0]
    assert float(mod.logdet) == per[j][1] and float(mod.aic) == per[j][2]
