"""Several lags in one computation (vbl.sysid.cva.fit_lags, padded to the largest lag) against
the independent NumPy oracle at each lag alone, and the in-program identifications (Tables 1
and 3's identify_one, the CVA learner's identify_object) against vbl.sysid.identify."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference.cva_np import cva_reference
from reference.sysid_systems import simulate_batch

from vbl.agents.cva_state import identify_object
from vbl.programs.identification import identify_one
from vbl.sysid import CVAParams, identify
from vbl.sysid.cva import first_argmin, fit_lags, n_identifiable

M, Q = 2, 3
LAGS = (1, 2, 3, 4)


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(7)
    u, y, _ = simulate_batch(rng, np.array([2, 3, 4]), 400, M, Q, noise=0.1,
                             min_separation=0.15)
    return u, y


@pytest.mark.parametrize("method", ["projected", "paper"])
def test_each_lag_equals_the_oracle_at_that_lag_alone(data, method):
    """Lag l of fit_lags (horizon 2l, its own sample window) = CVA at lag l alone: canonical
    correlations, log det R(n) and AIC(n) for every order l can identify, n*, the state map
    rows (up to sign) in the layout of the largest lag, zero beyond l; orders beyond l's
    identifiable order are invalid, its padded canonical correlations zero."""
    u, y = data
    p = CVAParams(method=method)
    hors = tuple(2 * lg for lg in LAGS)
    cap = max(n_identifiable(lg, k, M, Q) for lg, k in zip(LAGS, hors, strict=True))
    with jax.enable_x64(True):
        fits = jax.jit(jax.vmap(lambda a, b: fit_lags(a, b, p, lags=LAGS, horizons=hors,
                                                      n_cap=cap)))(u, y)
    h = max(LAGS)
    for i in range(len(u)):
        for j, (lag, k) in enumerate(zip(LAGS, hors, strict=True)):
            ref = cva_reference(u[i], y[i], lag, k, method=method)
            r = n_identifiable(lag, k, M, Q)
            cc = np.asarray(fits.cancor[i, j])
            np.testing.assert_allclose(cc[:r], ref["cancor"], atol=1e-10)
            assert np.all(cc[r:] == 0.0)
            ld, ai = np.asarray(fits.logdet[i, j]), np.asarray(fits.aic[i, j])
            np.testing.assert_allclose(ld[:r + 1], ref["logdet"], atol=1e-7)
            fin = np.isfinite(ref["aic"])
            np.testing.assert_allclose(ai[:r + 1][fin], ref["aic"][fin], atol=1e-4)
            assert not np.isfinite(ai[r + 1:]).any()
            assert int(fits.n[i, j]) == ref["n"]
            um = np.asarray(fits.U[i, j])[:r]                     # (r, h (m+q))
            beyond = np.r_[lag * M:h * M, h * M + lag * Q:h * (M + Q)]
            assert np.all(um[:, beyond] == 0.0)
            um = np.delete(um, beyond, axis=1)
            n = ref["n"]
            cos = np.abs(np.sum(um[:n] * ref["U"][:n], 1)) / (
                np.linalg.norm(um[:n], axis=1) * np.linalg.norm(ref["U"][:n], axis=1))
            np.testing.assert_allclose(cos, 1.0, atol=1e-8)


def test_lag_caps_fit_each_lag_as_alone_at_its_cap(data):
    """With one order cap per lag (identify_object's), lag j of fit_lags equals a fit of
    that lag alone swept to its own cap: orders beyond the cap invalid, its components
    beyond it zero, and the order sweep's regularisation floor that of its own cap (a large
    floor makes the floor visible: the common cap gives other log dets)."""
    u, y = data
    p = CVAParams(reg=1e-2)
    hors = tuple(2 * lg for lg in LAGS)
    caps = tuple(min(7, n_identifiable(lg, k, M, Q)) for lg, k in zip(LAGS, hors, strict=True))
    with jax.enable_x64(True):
        both = jax.jit(jax.vmap(lambda a, b: (
            fit_lags(a, b, p, lags=LAGS, horizons=hors, n_cap=max(caps), lag_caps=caps),
            fit_lags(a, b, p, lags=LAGS, horizons=hors, n_cap=max(caps)))))
        fits, common = both(u, y)
        for j, (lag, k, c) in enumerate(zip(LAGS, hors, caps, strict=True)):
            alone = jax.jit(jax.vmap(lambda a, b, lag=lag, k=k, c=c: fit_lags(
                a, b, p, lags=(lag,), horizons=(k,), n_cap=c)))(u, y)
            alone = jax.tree_util.tree_map(lambda a: a[:, 0], alone)
            np.testing.assert_allclose(np.asarray(fits.logdet[:, j, :c + 1]),
                                       np.asarray(alone.logdet), rtol=1e-10, atol=1e-10)
            assert not np.isfinite(np.asarray(fits.aic[:, j, c + 1:])).any()
            np.testing.assert_array_equal(np.asarray(fits.n[:, j]), np.asarray(alone.n))
            np.testing.assert_allclose(np.asarray(fits.cancor[:, j, :c]),
                                       np.asarray(alone.cancor), atol=1e-12)
            assert np.all(np.asarray(fits.cancor[:, j, c:]) == 0.0)
            assert np.all(np.asarray(fits.U[:, j, c:]) == 0.0)
            if c < max(caps):   # the common cap's floor differs from the lag's own
                assert np.max(np.abs(np.asarray(common.logdet[:, j, 1:c + 1])
                                     - np.asarray(alone.logdet[:, 1:]))) > 1e-6
    with pytest.raises(ValueError, match="lag_caps"):
        fit_lags(u[0], y[0], p, lags=LAGS, horizons=hors, n_cap=3, lag_caps=caps)


@pytest.mark.parametrize("params", [
    CVAParams(lag_rule="paper", lag_max=3, standardize=False),
    CVAParams(lag_rule="paper", lag_max=3, logdet_stop=-100.0),
    CVAParams(lag=2),
    CVAParams(lag_max=5, lag_min=2, lag_step=3),
], ids=["paper", "paper-no-stop", "fixed", "predictor"])
def test_in_program_identification_equals_identify(data, params):
    """identify_one and identify_object (every lag fitted in one jitted program) choose the
    lag and order identify chooses (a host loop over lags that stops early for 'paper'),
    with its log det R and AIC, and the same state map rows. identify_object applies the
    paper's rule whatever lag_rule says, so it is compared for 'paper' and a fixed lag."""
    u, y = data
    y = 30.0 * y + 5.0      # raw units: log det R > 0, so the paper rule's AIC part runs
    ref = identify(u, y, params, model_dtype=jnp.float64)
    with jax.enable_x64(True):
        got, model = jax.jit(jax.vmap(lambda a, b: identify_one(a, b, params)))(u, y)
    np.testing.assert_array_equal(np.asarray(got["l"]), np.asarray(ref.lag))
    np.testing.assert_array_equal(np.asarray(got["n"]), np.asarray(ref.n))
    np.testing.assert_allclose(np.asarray(got["logdet_R"]), np.asarray(ref.logdet_R),
                               rtol=1e-9)
    np.testing.assert_allclose(np.asarray(got["aic"]), np.asarray(ref.aic), rtol=1e-9)
    ru = np.asarray(ref.model.U)  # the model's state map (history max(lags)), up to sign
    np.testing.assert_allclose(np.abs(np.asarray(model.U)), np.abs(ru), atol=1e-8)
    if params.lag == 0 and params.lag_rule == "predictor":
        return
    with jax.enable_x64(True):
        obj = jax.jit(jax.vmap(lambda a, b: identify_object(a, b, params, 3)))(u, y)
    np.testing.assert_array_equal(np.asarray(obj.lag), np.asarray(ref.lag))
    np.testing.assert_array_equal(np.asarray(obj.n), np.asarray(ref.n))
    np.testing.assert_allclose(np.asarray(obj.logdet), np.asarray(ref.logdet_R), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(obj.aic), np.asarray(ref.aic), rtol=1e-6)
    h = max(params.lags())
    rows = np.concatenate([np.asarray(obj.Uu).reshape(len(u), 3, h * M),
                           np.asarray(obj.Uy).reshape(len(u), 3, h * Q)], axis=2)
    np.testing.assert_allclose(np.abs(rows), np.abs(ru[:, :3]), rtol=1e-4, atol=1e-5)


def test_first_argmin_is_the_first_minimum_inside_jit_vmap():
    """The first index of the minimum (ties, inf entries) in a jit(vmap) with 64-bit types
    switched on only inside the call, as the identification programs run it."""
    a = np.array([[np.inf, 3.0, 1.0, 1.0, 2.0], [np.inf] * 5, [5.0, 4.0, 3.0, 2.0, 2.0]])
    with jax.enable_x64(True):
        got = jax.jit(jax.vmap(first_argmin))(jnp.asarray(a))
    np.testing.assert_array_equal(np.asarray(got), [2, 0, 3])
