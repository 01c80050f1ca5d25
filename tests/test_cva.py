"""CVA identification (vbl.sysid) against the independent NumPy oracle and invariants."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference.cva_np import cva_reference
from reference.sysid_systems import simulate_batch

from vbl.params import ParamError
from vbl.sysid import CVAParams, identify, param_count, select_lag

LAG, HOR = 2, 4


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(42)
    orders = np.array([1, 2, 3, 4, 2, 3])
    u, y, poles = simulate_batch(rng, orders, 400, 2, 2, noise=0.05, min_separation=0.15)
    return u, y, orders


def _fit(data, method):
    u, y, _ = data
    p = CVAParams(lag=LAG, horizon=HOR, method=method)
    return method, p, identify(u, y, p, model_dtype=jnp.float64)


@pytest.fixture(scope="module", params=["projected", "paper"])
def fitted(request, data):
    return _fit(data, request.param)


@pytest.fixture(scope="module")
def projected(data):
    return _fit(data, "projected")


def test_param_count_analytic():
    # Larimore: n(2q+m) + qm + q(q+1)/2 ; SIPPY: n(q+m) + qm
    assert float(param_count(2, 2, 4)) == 2 * 10 + 8 + 10
    assert float(param_count(3, 1, 2, "sippy")) == 3 * 3 + 2


def test_matches_numpy_oracle(data, fitted):
    u, y, _ = data
    method, _, res = fitted
    for i in range(len(u)):
        ref = cva_reference(u[i], y[i], LAG, HOR, method=method)
        np.testing.assert_allclose(np.asarray(res.cancor[i]), ref["cancor"], atol=1e-10)
        np.testing.assert_allclose(np.asarray(res.logdet_curve[i]), ref["logdet"], atol=1e-7)
        fin = np.isfinite(ref["aic"])
        np.testing.assert_array_equal(np.isfinite(np.asarray(res.aic_curve[i])), fin)
        np.testing.assert_allclose(np.asarray(res.aic_curve[i])[fin], ref["aic"][fin],
                                   atol=1e-4)
        assert int(res.n[i]) == ref["n"]
        # state map rows agree up to sign (Cholesky vs symmetric whitening)
        ur = ref["U"][: int(res.n[i])]
        uj = np.asarray(res.model.U[i])[: int(res.n[i])]

        uj = _unpad(uj, LAG, LAG, 2, 2)
        np.testing.assert_allclose(np.abs(np.sum(ur * uj, 1)) /
                                   (np.linalg.norm(ur, axis=1) * np.linalg.norm(uj, axis=1)),
                                   1.0, atol=1e-8)
        # poles of A are invariant to the sign/basis of the state (clusters of near-zero
        # poles of over-fitted paper-recipe models are ill-conditioned: 1e-4)
        model_i = jax.tree_util.tree_map(lambda a, i=i: a[i], res.model)
        np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(ref["A"])),
                                   np.sort_complex(model_i.poles()), atol=1e-4)


def _unpad(umat, lag, h, m, q):
    return np.concatenate([umat[:, :lag * m], umat[:, h * m:h * m + lag * q]], axis=1)


def test_batched_equals_single(data, projected):
    u, y, _ = data
    _, p, res = projected
    one = identify(u[2], y[2], p, model_dtype=jnp.float64)
    assert int(one.n) == int(res.n[2]) and int(one.lag) == int(res.lag[2])
    np.testing.assert_allclose(np.asarray(one.aic_curve), np.asarray(res.aic_curve[2]),
                               rtol=1e-9)
    np.testing.assert_allclose(np.asarray(one.model.U), np.asarray(res.model.U[2]),
                               atol=1e-10)


def test_float32_agrees_with_float64(data, projected):
    u, y, _ = data
    _, p, res = projected
    r32 = identify(u, y, p.replace(dtype="float32"))
    np.testing.assert_allclose(np.asarray(r32.cancor), np.asarray(res.cancor), atol=2e-4)
    np.testing.assert_array_equal(np.asarray(r32.n), np.asarray(res.n))
    np.testing.assert_allclose(np.asarray(r32.logdet_R), np.asarray(res.logdet_R), atol=1e-3)


def test_model_filter_reproduces_residual_covariance(data, fitted):
    """Running the model through the data gives the residual covariance R_hat(n*)."""
    u, y, _ = data
    _, _, res = fitted
    model = res.model

    def run(mdl, uu, yy):
        def step(h, uy):
            yh = mdl.predict(h, uy[0])
            mu = mdl.state(h)
            return mdl.update_history(h, uy[0], uy[1]), (yh, mu)
        return jax.lax.scan(step, mdl.init_history(), (uu, yy))[1]

    yh, mu = jax.jit(jax.vmap(run))(model, jnp.asarray(u), jnp.asarray(y))
    n = np.asarray(res.n)
    for i in range(len(u)):
        e = ((y[i] - np.asarray(yh[i])) / np.asarray(model.y_scale[i]))[LAG:len(y[i]) - HOR + 1]
        np.testing.assert_allclose(e.T @ e / len(e), np.asarray(model.R[i]), atol=1e-7)
        assert np.all(np.asarray(mu[i])[:, n[i]:] == 0.0)   # masked beyond n*
    assert mu.shape[-1] == model.n_max


def test_model_default_dtype_float32(data):
    u, y, _ = data
    res = identify(u, y, CVAParams(lag=LAG, horizon=HOR))
    m0 = jax.tree_util.tree_map(lambda a: a[0], res.model)
    h = m0.update_history(m0.init_history(), jnp.ones(2, jnp.float32), jnp.ones(2, jnp.float32))
    assert m0.state(h).dtype == jnp.float32 and h.u.dtype == jnp.float32
    assert bool(m0.ready(h)) is (LAG <= 1)


def test_select_lag_rule():
    nan = np.nan
    # rows: stops at l=1 by log det < 0; stops at l=2 (AIC rises at 3); never stops (cap);
    # log det < 0 reached at l=3 while AIC keeps falling
    logdet = np.array([[-0.1, 0.5, 0.4], [0.9, 0.5, 0.4], [0.9, 0.5, 0.4], [0.9, 0.5, -0.2]])
    aic = np.array([[10., 9., 8.], [10., 8., 9.], [10., 9., 8.], [10., 9., 8.]])
    chosen, decided = select_lag(logdet, aic, 0.0)
    np.testing.assert_array_equal(chosen, [0, 1, 2, 2])
    np.testing.assert_array_equal(decided, [True, True, False, True])
    chosen, _ = select_lag(np.array([[0.9, nan]]), np.array([[10., nan]]), 0.0)
    assert chosen[0] == 0  # the last lag identified (l = 2 was not)


def test_paper_lag_rule_end_to_end(data):
    """lag_rule='paper' (Sec. 3.1.2, the named option Tables 1 and 3 use)."""
    u, y, _ = data
    # raw (unstandardised) outputs scaled up: log det R > 0 so the AIC part of the rule runs
    p = CVAParams(lag=0, lag_max=2, standardize=False, lag_rule="paper")
    res = identify(u, 30.0 * y, p)
    ld, ai = np.asarray(res.lag_logdet), np.asarray(res.lag_aic)
    chosen, _ = select_lag(ld, ai, 0.0)
    np.testing.assert_array_equal(np.asarray(res.lag), chosen + 1)
    assert np.all(np.asarray(res.aic) == ai[np.arange(len(u)), chosen])
    # standardised, low-noise data: log det R < 0 already at l = 1, so the paper rule stops
    # there whatever the data (why it is not the default)
    res1 = identify(u, y, CVAParams(lag=0, lag_max=2, lag_rule="paper"))
    assert np.all(np.asarray(res1.lag) == 1) and np.all(np.asarray(res1.logdet_R) < 0)


@pytest.mark.parametrize("case, msg", [
    ("nan", "NaN or inf"), ("inf", "NaN or inf"), ("const", "constant"),
    ("short", "too short"), ("shape", "share"), ("ndim", "must both be")])
def test_bad_input_errors(data, case, msg):
    u, y, _ = data
    u, y = u[:2].copy(), y[:2].copy()
    if case == "nan":
        y[1, 5, 0] = np.nan
    elif case == "inf":
        u[0, 7, 1] = np.inf
    elif case == "const":
        y[1, :, 1] = 3.0
    elif case == "short":
        u, y = u[:, :20], y[:, :20]
    elif case == "shape":
        y = y[:, :-1]
    elif case == "ndim":
        u = u[0]
    with pytest.raises(ValueError, match=msg):
        identify(u, y, CVAParams(lag=LAG, horizon=HOR))


def test_bad_params():
    with pytest.raises(ParamError):
        identify(np.zeros((50, 1)), np.zeros((50, 1)), CVAParams(method="n4sid"))
    with pytest.raises(ParamError):
        identify(np.zeros((50, 1)), np.zeros((50, 1)), CVAParams(lag=7, lag_max=6))
