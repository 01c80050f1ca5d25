"""Order recovery with identify's DEFAULT parameters on random stable systems of known
order 1-6 (m = q = 2, white inputs).

Documented setting (docs/sysid.md): N = 1000, measurement noise std = 5% of each output's
std, poles |z| in [0.5, 0.95] at least 0.15 apart; ``identify(u, y)`` as a new user calls
it (lag by the predictor AIC over l = 1..6, k = 2l, n by AIC).
"""

import numpy as np
import pytest
from reference.sysid_systems import pole_error, simulate_batch

from vbl.sysid import CVAParams, identify

N, NOISE, SEP = 1000, 0.05, 0.15


def _run(draws: int, seed: int, params: CVAParams | None = None, noise: float = NOISE,
         show: bool = False):
    rng = np.random.default_rng(seed)
    orders = rng.integers(1, 7, draws)
    u, y, poles = simulate_batch(rng, orders, N, 2, 2, noise=noise, min_separation=SEP)
    res = identify(u, y) if params is None else identify(u, y, params)
    n = np.asarray(res.n)
    errs = []
    for i in np.flatnonzero(n == orders):
        a = np.asarray(res.model.A[i], np.float64)[:n[i], :n[i]]
        errs.append(pole_error(poles[i], np.linalg.eigvals(a)))
    if show:                                   # the rows of docs/sysid.md (pytest -s)
        lags, counts = np.unique(np.asarray(res.lag), return_counts=True)
        print(f"| defaults, noise {noise:.0%} | {draws} ({seed}) | {(n == orders).mean():.1%} | "
              f"{np.median(errs):.4f} / {np.quantile(errs, 0.9):.3f} | "
              + ", ".join(f"{lg}: {c}" for lg, c in zip(lags, counts, strict=True)) + " |")
    return (n == orders).mean(), np.asarray(errs)


def test_order_recovery_defaults():
    rate, errs = _run(200, 0)
    assert rate >= 0.93, rate
    assert np.median(errs) < 0.01 and np.quantile(errs, 0.9) < 0.05, np.quantile(errs, [.5, .9])


@pytest.mark.slow
def test_order_recovery_large():
    rate, errs = _run(1000, 1)
    rate_paper, _ = _run(1000, 1, CVAParams(lag=4, method="paper"))
    rate_rule, _ = _run(1000, 1, CVAParams(lag_rule="paper"))
    assert rate >= 0.93, rate
    assert rate > rate_paper + 0.2, (rate, rate_paper)
    assert rate > rate_rule + 0.2, (rate, rate_rule)   # the paper's lag rule stops at l = 1
    assert np.median(errs) < 0.01


@pytest.mark.slow
def test_order_recovery_rows():
    """The default rows of docs/sysid.md's recovery table (printed with -s)."""
    for draws, seed, noise in ((100, 7, NOISE), (200, 0, NOISE), (300, 1, NOISE),
                               (1000, 1, NOISE), (300, 0, 0.15)):
        rate, _ = _run(draws, seed, noise=noise, show=True)
        assert rate >= (0.93 if noise == NOISE else 0.8), (draws, seed, noise, rate)
