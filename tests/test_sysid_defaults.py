"""identify(u, y) with its defaults: the predictor lag rule against the NumPy oracle, the
order-cap and collinearity warnings, and data near float limits."""

import warnings

import numpy as np
import pytest
from reference.cva_np import cva_reference
from reference.sysid_systems import simulate_batch

from vbl.sysid import CVAParams, identify, param_count
from vbl.sysid.lag import OrderCapWarning
from vbl.sysid.validate import CollinearWarning

LAG_MAX = 3


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(7)
    u, y, _ = simulate_batch(rng, np.array([1, 3, 5, 2]), 500, 2, 2, noise=0.05,
                             min_separation=0.15)
    return u, y


def _standardised(x):
    return (x - x.mean(axis=1, keepdims=True)) / x.std(axis=1, keepdims=True)


def test_predictor_rule_matches_oracle_on_common_window(data):
    """Every lag l = lag_min .. L is the oracle's CVA on the common window t = L .. N-K; n*
    minimises sum_l [N_e log det R_l(n) + 3 lambda(n)] over the n every lag can give; l*
    minimises AIC_l(n*) + 2 n* l (m+q); the result is the oracle's fit at l*."""
    u, y = map(_standardised, data)
    p = CVAParams(lag_max=LAG_MAX, lag_step=1)
    res = identify(u, y, p)
    m = q = 2
    big_k = 2 * LAG_MAX
    lags = np.arange(p.lag_min, LAG_MAX + 1)
    assert p.lags() == tuple(lags) == (2, 3)
    ne = u.shape[1] - big_k - LAG_MAX + 1
    cap = min(lg * (m + q) for lg in lags)          # n the shortest lag can give (k = 2l)
    lam = np.asarray(param_count(np.arange(cap + 1), m, q))
    for i in range(len(u)):
        refs = []
        for lag in lags:
            sl = slice(LAG_MAX - lag, u.shape[1] - (big_k - 2 * lag))
            refs.append(cva_reference(u[i, sl], y[i, sl], lag, 2 * lag, demean=False,
                                      standardize=False, n_max=12))
        ld = np.array([r["logdet"][:cap + 1] for r in refs])
        pooled = (ne * ld + 3.0 * lam).sum(0)
        n = 1 + int(np.argmin(pooled[1:]))
        aic_n = np.array([r["aic"][n] for r in refs])
        pe = aic_n + 2 * n * lags * (m + q)
        np.testing.assert_array_equal(np.asarray(res.lag_n[i]), [r["n"] for r in refs])
        np.testing.assert_allclose(np.asarray(res.lag_aic[i]), aic_n, atol=1e-4)
        np.testing.assert_allclose(np.asarray(res.lag_criterion[i]), pe, atol=1e-4)
        best = int(np.argmin(pe))
        assert int(res.lag[i]) == lags[best] and int(res.n[i]) == n
        ref = refs[best]
        assert res.cancor.shape[1] == cap                # orders beyond the pooled cap: none
        np.testing.assert_allclose(np.asarray(res.cancor[i]), ref["cancor"][:cap], atol=1e-9)
        np.testing.assert_allclose(np.asarray(res.logdet_curve[i]), ref["logdet"][:cap + 1],
                                   atol=1e-7)
        assert int(res.n_samples[i]) == ne


def test_hankel_gram_equals_window_product():
    """The Toeplitz-plus-edges Gram matrix equals Z^T Z of the explicit window matrix."""
    import jax

    from vbl.sysid.gram import hankel_gram

    x = np.random.default_rng(3).standard_normal((40, 3))
    w = 6
    z = np.stack([x[t:t + w].reshape(-1) for t in range(len(x) - w + 1)])
    with jax.enable_x64(True):
        g = np.asarray(hankel_gram(jax.numpy.asarray(x), w))
    np.testing.assert_allclose(g, z.T @ z, atol=1e-12)


@pytest.mark.parametrize("n,d,w,block", [(40, 3, 6, 1), (40, 3, 6, 4), (30, 2, 8, 6),
                                         (25, 1, 7, 3), (61, 4, 13, 9)])
def test_lag_products_equal_shifted_sums(n, d, w, block):
    """Every blocking of the record gives the lag products sum_t x(t+s) x(t)^T."""
    import jax

    from vbl.sysid.gram import lag_products

    x = np.random.default_rng(n + w).standard_normal((n, d))
    ne = n - w + 1
    with jax.enable_x64(True):
        f = np.asarray(lag_products(jax.numpy.asarray(x), w, block))
    np.testing.assert_allclose(f, [x[s:s + ne].T @ x[:ne] for s in range(w)], atol=1e-12)


def test_logdet_spd_equals_numpy():
    """log det by Gaussian elimination equals NumPy's slogdet; not positive definite: NaN."""
    import jax

    from vbl.sysid.sweep import logdet_spd

    a = np.random.default_rng(4).standard_normal((7, 5, 4, 9))
    spd = a @ np.swapaxes(a, -1, -2)
    with jax.enable_x64(True):
        got = np.asarray(logdet_spd(jax.numpy.asarray(spd)))
        bad = float(logdet_spd(jax.numpy.asarray(np.diag([1.0, -1.0, 2.0]))))
    np.testing.assert_allclose(got, np.linalg.slogdet(spd)[1], rtol=1e-12)
    assert np.isnan(bad)


def test_chunked_sweep_equals_one_batch(data):
    """Chunks (the last one padded) give the data sets' results of one unchunked batch, with
    the lag selected (fit_select_batch) and fixed (fit_batch)."""
    from vbl.sysid.batching import chunk_sizes
    from vbl.sysid.lag import n_cap_for
    from vbl.sysid.sweep import fit_batch, fit_select_batch

    assert chunk_sizes(11, 4) == [(4, 4), (4, 4), (3, 4)]
    assert chunk_sizes(5, 8) == [(5, 8)] and chunk_sizes(1, 8) == [(1, 1)]
    u, y = (np.concatenate([a, a[:1]]) for a in data)               # 5 data sets
    p = CVAParams(lag_max=LAG_MAX)
    c = n_cap_for(p, 2, 2)
    one = fit_select_batch(u, y, p, n_cap=c, chunk=8)
    parts = fit_select_batch(u, y, p, n_cap=c, chunk=2)
    np.testing.assert_array_equal(np.asarray(one[1]), np.asarray(parts[1]))
    np.testing.assert_array_equal(np.asarray(one[0].n), np.asarray(parts[0].n))
    np.testing.assert_allclose(np.asarray(one[2][3]), np.asarray(parts[2][3]), rtol=1e-9)
    # a fixed lag (fit_batch) likewise
    one = fit_batch(u, y, p, lag=2, horizon=4, n_cap=c, chunk=8)
    parts = fit_batch(u, y, p, lag=2, horizon=4, n_cap=c, chunk=2)
    np.testing.assert_array_equal(np.asarray(one.n), np.asarray(parts.n))
    np.testing.assert_allclose(np.asarray(one.aic), np.asarray(parts.aic), rtol=1e-9)


def test_predictor_rule_same_in_any_units(data):
    """A change of y's unit shifts log det R by the same constant at every lag: the lag and
    order stay, also without standardisation (where the paper rule's log det R < 0 stop
    moves: at 300x it never fires, at 0.01x it fires at l = 1)."""
    u, y = data
    a = identify(u, y, CVAParams(lag_max=LAG_MAX, standardize=False))
    for unit in (300.0, 0.01):
        b = identify(u, y * unit, CVAParams(lag_max=LAG_MAX, standardize=False))
        np.testing.assert_array_equal(np.asarray(a.lag), np.asarray(b.lag))
        np.testing.assert_array_equal(np.asarray(a.n), np.asarray(b.n))
        # identified components; the regularisation floor scales with the mean variance of
        # u and y together, so it moves the small (noise) correlations by up to ~1e-2
        for i, n in enumerate(np.asarray(a.n)):
            np.testing.assert_allclose(np.asarray(a.cancor[i, :n]), np.asarray(b.cancor[i, :n]),
                                       atol=1e-3)
        np.testing.assert_allclose(np.asarray(b.logdet_R) - np.asarray(a.logdet_R),
                                   2 * 2 * np.log(unit), atol=1e-2)


def test_order_cap_warning_and_field():
    """Order 6 with l = 1, k = 2: at most min(1 * 4, 2 * 2) = 4 states identifiable."""
    rng = np.random.default_rng(0)
    u, y, _ = simulate_batch(rng, np.array([6, 6]), 600, 2, 2, noise=0.01, min_separation=0.15)
    with pytest.warns(OrderCapWarning, match="largest identifiable order"):
        res = identify(u, y, CVAParams(lag=1))
    assert np.all(np.asarray(res.n_ident) == 4)
    np.testing.assert_array_equal(np.asarray(res.n_at_cap), np.asarray(res.n) == 4)
    assert np.asarray(res.n_at_cap).any()


def test_lags_tried():
    """The predictor rule tries lag_max, lag_max - lag_step, ... down to lag_min; the paper
    rule every l from 1."""
    assert CVAParams().lags() == (3, 6)
    assert CVAParams(lag_step=1).lags() == (2, 3, 4, 5, 6)
    assert CVAParams(lag_max=5, lag_step=2).lags() == (3, 5)
    assert CVAParams(lag_max=1).lags() == (1,)
    assert CVAParams(lag_rule="paper").lags() == (1, 2, 3, 4, 5, 6)
    assert CVAParams(lag=4).lags() == (4,)


def test_pooled_order_cap_warning():
    """The predictor rule pools l = lag_min .. lag_max: n* <= what l = lag_min = 1 gives
    (k = 2: min(1 * 4, 2 * 2) = 4), so order 6 hits that cap and warns."""
    rng = np.random.default_rng(0)
    u, y, _ = simulate_batch(rng, np.array([6, 6]), 600, 2, 2, noise=0.01, min_separation=0.15)
    with pytest.warns(OrderCapWarning, match="smallest lag pooled"):
        res = identify(u, y, CVAParams(lag_min=1, lag_max=3, lag_step=2))
    assert np.all(np.asarray(res.n_ident) == 4) and np.all(np.asarray(res.n) == 4)
    assert np.asarray(res.n_at_cap).all()


def test_no_cap_warning_when_order_is_below_cap(data):
    u, y = data
    with warnings.catch_warnings():
        warnings.simplefilter("error", OrderCapWarning)
        res = identify(u, y, CVAParams(lag=3))
    assert not np.asarray(res.n_at_cap).any()


@pytest.mark.parametrize("params", [CVAParams(lag=2), CVAParams()], ids=["fixed", "default"])
def test_duplicate_output_channel_warning(data, params):
    """A duplicated output channel is named, and the fit stays finite (the past's covariance
    is singular: the states' covariance needs more than the regularisation floor)."""
    u, y = data
    y3 = np.concatenate([y, -2.5 * y[..., :1]], axis=-1)
    with pytest.warns(CollinearWarning, match="y channels 0 and 2 are duplicates"):
        res = identify(u, y3, params)
    assert np.all(np.isfinite(np.asarray(res.logdet_R)))
    assert np.all(np.isfinite(np.asarray(res.model.A)))


@pytest.mark.parametrize("params", [CVAParams(lag=2), CVAParams()], ids=["fixed", "default"])
def test_collinear_input_warning(data, params):
    u, y = data
    u3 = np.concatenate([u, u[..., :1] - 0.5 * u[..., 1:]], axis=-1)
    with pytest.warns(CollinearWarning, match="u channels are collinear"):
        res = identify(u3, y, params)
    assert np.all(np.isfinite(np.asarray(res.logdet_R)))


def test_no_collinear_warning_on_clean_data(data):
    with warnings.catch_warnings():
        warnings.simplefilter("error", CollinearWarning)
        identify(*data, CVAParams(lag=2))


def _finite_model(res):
    for k in ("U", "A", "B", "C", "D", "R", "u_mean", "u_scale", "y_mean", "y_scale"):
        assert np.all(np.isfinite(np.asarray(getattr(res.model, k)))), k


@pytest.mark.parametrize("scale", [1e100, 1e-100])
def test_huge_and_tiny_values_are_handled(data, scale):
    """Standardised identification of data scaled by 1e+-100 is the same identification
    (exact power-of-two prescaling); the model maps raw units."""
    u, y = data
    p = CVAParams(lag=2)
    ref = identify(u, y, p)
    with pytest.raises(ValueError, match="do not fit the float32 filtering model"):
        identify(u * scale, y * scale, p)
    res = identify(u * scale, y * scale, p, model_dtype=np.float64)
    _finite_model(res)
    np.testing.assert_array_equal(np.asarray(res.n), np.asarray(ref.n))
    np.testing.assert_allclose(np.asarray(res.cancor), np.asarray(ref.cancor), atol=1e-12)
    np.testing.assert_allclose(np.asarray(res.logdet_R), np.asarray(ref.logdet_R), atol=1e-9)
    np.testing.assert_allclose(np.asarray(res.model.y_scale, np.float64),
                               scale * np.asarray(ref.model.y_scale, np.float64), rtol=1e-6)


def test_huge_values_without_standardisation_error(data):
    u, y = data
    with pytest.raises(ValueError, match="reaches .*e\\+100 in magnitude.*standardize=True"):
        identify(u, y * 1e100, CVAParams(lag=2, standardize=False))


def test_float32_with_large_means(data):
    """Means around 1e7 with the float32 kernel: the means are removed in float64 first, so
    float32 identifies as float64 does (a float32 mean removal would keep ~1 digit)."""
    u, y = data
    r64 = identify(u + 1e7, y - 3e7, CVAParams(lag=2))
    r32 = identify(u + 1e7, y - 3e7, CVAParams(lag=2, dtype="float32"))
    _finite_model(r32)
    np.testing.assert_array_equal(np.asarray(r32.n), np.asarray(r64.n))
    np.testing.assert_allclose(np.asarray(r32.cancor), np.asarray(r64.cancor), atol=2e-4)
    np.testing.assert_allclose(np.asarray(r32.model.y_mean[0]), y[0].mean(0) - 3e7, rtol=1e-7)


def test_ill_conditioned_message_names_the_cause(data):
    """Without any regularisation floor, duplicated channels make the covariances singular:
    the error says so (and not for the scaled data above, which is handled)."""
    u, y = data
    u3 = np.concatenate([u, u[..., :1]], axis=-1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CollinearWarning)
        try:
            res = identify(u3, y, CVAParams(lag=2, reg=0.0))
        except ValueError as e:
            assert "ill-conditioned" in str(e) and "raise params.reg" in str(e)
        else:
            _finite_model(res)


def test_param_count_used_by_criterion():
    # the predictor criterion adds n l (m+q) coefficients of the state map to Eq. (6)'s count
    assert float(param_count(3, 2, 2)) + 3 * 2 * 4 == 3 * 6 + 4 + 3 + 24


def test_channel_stats_match_numpy_at_any_scale(data):
    """identify's one-pass channel statistics equal NumPy's std, max |x| and corrcoef, also
    for channels near the float limits (scaled before squaring: no overflow or underflow)."""
    from vbl.sysid.validate import channel_stats

    u, y = data
    x = np.concatenate([y, 1e200 * y[..., :1] + 3e199, 1e-200 * u[..., :1]], axis=-1)
    st = channel_stats(x)
    for b in range(len(x)):
        scale = np.abs(x[b]).max(axis=0)        # NumPy's std of x itself over/underflows
        np.testing.assert_allclose(st.abs_max[b], scale, rtol=0)
        np.testing.assert_allclose(st.std[b], (x[b] / scale).std(axis=0) * scale, rtol=1e-12)
        np.testing.assert_allclose(st.corr[b], np.corrcoef((x[b] / scale).T), atol=1e-12)
