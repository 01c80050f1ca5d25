"""Order recovery on random stable systems of known order 1-6 (m = q = 2, white inputs).

Documented setting (docs/sysid.md): N = 1000, measurement noise std = 5% of each output's
std, poles |z| in [0.5, 0.95] at least 0.15 apart, fixed lag l = 4, k = 2l = 8.
"""

import numpy as np
import pytest
from reference.sysid_systems import pole_error, simulate_batch

import vbl  # noqa: F401
from vbl.sysid import CVAParams, identify

N, NOISE, SEP, LAG = 1000, 0.05, 0.15, 4


def _run(draws: int, seed: int, method: str):
    rng = np.random.default_rng(seed)
    orders = rng.integers(1, 7, draws)
    u, y, poles = simulate_batch(rng, orders, N, 2, 2, noise=NOISE, min_separation=SEP)
    res = identify(u, y, CVAParams(lag=LAG, method=method))
    n = np.asarray(res.n)
    errs = []
    for i in np.flatnonzero(n == orders):
        a = np.asarray(res.model.A[i], np.float64)[:n[i], :n[i]]
        errs.append(pole_error(poles[i], np.linalg.eigvals(a)))
    return (n == orders).mean(), np.asarray(errs)


def test_order_recovery_projected():
    rate, errs = _run(200, 0, "projected")
    assert rate >= 0.90, rate
    assert np.median(errs) < 0.02 and np.quantile(errs, 0.9) < 0.06, np.quantile(errs, [.5, .9])


@pytest.mark.slow
def test_order_recovery_large():
    rate, errs = _run(1000, 1, "projected")
    rate_paper, _ = _run(1000, 1, "paper")
    assert rate >= 0.90, rate
    assert rate > rate_paper + 0.2, (rate, rate_paper)
    assert np.median(errs) < 0.02
