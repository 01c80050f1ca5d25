"""Tests of vbl.spaces.quantize: uniform bins and k-means vector quantisation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.params import ParamError
from vbl.spaces.quantize import (
    QuantizerParams,
    distortion,
    fit_quantizer,
    kmeans,
    make_quantizer,
    nearest,
    num_states,
    quantize,
)

# as the engine runs them: with 64-bit types on (conftest.engine_precision)
pytestmark = pytest.mark.usefixtures("engine_precision")


def numpy_lloyd(x, init, iters):
    """Independent reference: plain Lloyd iterations, empty clusters keep their centre."""
    c = np.array(init, dtype=np.float64)
    for _ in range(iters):
        d = ((x[:, None, :] - c[None, :, :]) ** 2).sum(-1)
        a = d.argmin(1)
        for j in range(len(c)):
            if np.any(a == j):
                c[j] = x[a == j].mean(0)
    return c


def test_bins_map_known_points():
    # two components fitted on uniform grids over [0, 4] and [-1, 1] with no quantile trimming
    g = np.stack([np.linspace(0, 4, 401), np.linspace(-1, 1, 401)], axis=1)
    p = QuantizerParams(method="bins", bins=4, range_quantile=0.0)
    qz = fit_quantizer(jax.random.PRNGKey(0), jnp.asarray(g), p)
    np.testing.assert_allclose(qz.lo, [0, -1], atol=1e-6)
    np.testing.assert_allclose(qz.hi, [4, 1], atol=1e-6)
    pts = jnp.array([[0.5, -0.9], [1.5, -0.9], [3.9, -0.9], [0.5, 0.1], [3.5, 0.9],
                     [-10.0, 10.0], [100.0, -100.0]], jnp.float32)
    # component 0 bins: [0,1),[1,2),[2,3),[3,4]; comp 1: [-1,-.5),[-.5,0),[0,.5),[.5,1]
    # index = b0 + 4 * b1; outside the range -> edge bins
    expected = [0, 1, 3, 0 + 4 * 2, 3 + 4 * 3, 0 + 4 * 3, 3 + 4 * 0]
    idx = quantize(qz, pts)
    assert idx.dtype == jnp.int32
    np.testing.assert_array_equal(np.asarray(idx), expected)
    assert qz.num_states == num_states(p, 2) == 16


def test_bins_range_quantile_ignores_outliers_and_mask():
    x = np.concatenate([np.linspace(0, 1, 1000), [1e6]])[:, None]
    p = QuantizerParams(method="bins", bins=2, range_quantile=0.01)
    qz = fit_quantizer(jax.random.PRNGKey(0), jnp.asarray(x), p)
    assert float(qz.hi[0]) < 1.5  # the 1e6 outlier does not stretch the range
    mask = np.ones(len(x), bool)
    mask[-1] = False
    qz2 = fit_quantizer(jax.random.PRNGKey(0), jnp.asarray(x), p, mask=jnp.asarray(mask))
    np.testing.assert_allclose(qz2.hi, [np.quantile(x[:-1, 0], 0.99)], rtol=1e-5)


def test_nearest_is_numpy_argmin_with_ties_and_nan():
    # small integers: many tied minima per row; two rows with NaN (argmin: the first NaN)
    rng = np.random.default_rng(3)
    d = rng.integers(0, 4, (500, 64)).astype(np.float32)
    d[7, [9, 30]] = np.nan
    d[11, 0] = np.nan
    d[12] = 2.0  # all tied
    got = np.asarray(jax.jit(jax.vmap(nearest))(jnp.asarray(d.reshape(5, 100, 64))))
    np.testing.assert_array_equal(got.ravel(), np.argmin(d, axis=1))
    assert got.dtype == np.int32


def test_vq_maps_points_to_nearest_code():
    centres = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    rng = np.random.default_rng(0)
    lab = rng.integers(0, 3, 600)
    x = centres[lab] + 0.1 * rng.standard_normal((600, 2))
    p = QuantizerParams(method="vq", num_codes=3, kmeans_iters=10)
    qz = fit_quantizer(jax.random.PRNGKey(1), jnp.asarray(x), p)
    codes = np.asarray(qz.codebook) * np.asarray(qz.scale) + np.asarray(qz.mean)
    # every true centre has a code within 0.1 (k-means++ seeds one per blob)
    match = np.argmin(((centres[:, None] - codes[None]) ** 2).sum(-1), axis=1)
    np.testing.assert_allclose(codes[match], centres, atol=0.1)
    # a point is mapped to the code of its blob
    idx = np.asarray(quantize(qz, jnp.asarray(centres + 0.3)))
    np.testing.assert_array_equal(idx, match)
    # the data's labels are a relabelling of the quantiser's codes
    got = np.asarray(quantize(qz, jnp.asarray(x)))
    np.testing.assert_array_equal(got, match[lab])


def test_kmeans_matches_numpy_reference():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((200, 3))
    init = x[:5].copy()
    ref = numpy_lloyd(x, init, 20)
    got = kmeans(jax.random.PRNGKey(0), jnp.asarray(x), 5, 20, init=jnp.asarray(init))
    np.testing.assert_allclose(np.asarray(got), ref, rtol=1e-9, atol=1e-9)


def test_kmeans_reduces_distortion_vs_random_codebook():
    rng = np.random.default_rng(4)
    x = jnp.asarray(rng.standard_normal((2000, 4)), jnp.float32)
    k = 32
    rand_codes = jax.random.normal(jax.random.PRNGKey(5), (k, 4), jnp.float32)
    sub_codes = x[:k]  # k random data points (the data are i.i.d.)
    fitted = kmeans(jax.random.PRNGKey(6), x, k, 25)
    d_fit = float(distortion(x, fitted))
    assert d_fit < 0.8 * float(distortion(x, rand_codes))
    assert d_fit < 0.8 * float(distortion(x, sub_codes))
    # Lloyd never increases distortion from its seed
    seed_only = kmeans(jax.random.PRNGKey(6), x, k, 0)
    assert d_fit <= float(distortion(x, seed_only)) + 1e-6


def test_vmap_over_learners_equals_single_fits():
    rng = np.random.default_rng(7)
    xs = jnp.asarray(rng.standard_normal((3, 300, 2)), jnp.float32)
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    for p in (QuantizerParams(method="vq", num_codes=8, kmeans_iters=5),
              QuantizerParams(method="bins", bins=3)):
        fit = jax.jit(jax.vmap(lambda k, x, p=p: fit_quantizer(k, x, p)))
        qzs = fit(keys, xs)
        idx = jax.vmap(quantize)(qzs, xs)
        assert idx.shape == (3, 300) and idx.dtype == jnp.int32
        for b in range(3):
            one = fit_quantizer(keys[b], xs[b], p)
            np.testing.assert_array_equal(np.asarray(quantize(one, xs[b])), np.asarray(idx[b]))
        assert int(idx.max()) < num_states(p, 2) and int(idx.min()) >= 0


def test_bad_input_errors():
    with pytest.raises(ParamError, match="method"):
        make_quantizer(QuantizerParams(method="kd-tree"), 2)
    with pytest.raises(ParamError, match="bins"):
        make_quantizer(QuantizerParams(method="bins", bins=0), 2)
    with pytest.raises(ParamError, match="max_states"):
        make_quantizer(QuantizerParams(method="bins", bins=10, max_states=1000), 4)
    with pytest.raises(ParamError, match="dimension"):
        make_quantizer(QuantizerParams(), 0)


def test_product_vq_is_mixed_radix_of_per_group_nearest_codes():
    # two groups: 2-d blobs at 3 places (group 0) x a 1-d value at 2 places (group 1); a
    # per-group NumPy nearest-code search on the fitted codebooks is the reference
    rng = np.random.default_rng(0)
    centres0 = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0]])
    centres1 = np.array([[-3.0], [3.0]])
    i0, i1 = rng.integers(0, 3, 600), rng.integers(0, 2, 600)
    x = np.concatenate([centres0[i0] + 0.1 * rng.normal(size=(600, 2)),
                        centres1[i1] + 0.1 * rng.normal(size=(600, 1))], axis=1)
    p = QuantizerParams(method="product_vq", group_codes=(3, 2), kmeans_iters=20)
    qz = fit_quantizer(jax.random.PRNGKey(1), jnp.asarray(x), p, groups=(2, 1))
    assert qz.num_states == 6 == num_states(p, 3)
    z = (x - np.asarray(qz.mean)) / np.asarray(qz.scale)
    book = np.asarray(qz.codebook)
    b0, b1 = book[:3, :2], book[3:, 2:]
    assert np.all(book[:3, 2:] == 0) and np.all(book[3:, :2] == 0)
    c0 = ((z[:, None, :2] - b0[None]) ** 2).sum(-1).argmin(1)
    c1 = ((z[:, None, 2:] - b1[None]) ** 2).sum(-1).argmin(1)
    np.testing.assert_array_equal(np.asarray(quantize(qz, jnp.asarray(x))), c0 + 3 * c1)
    # the blobs are well separated: each (blob, value) pair gets its own state
    idx = np.asarray(quantize(qz, jnp.asarray(x)))
    pairs = {(a, b): set(idx[(i0 == a) & (i1 == b)]) for a in range(3) for b in range(2)}
    assert all(len(v) == 1 for v in pairs.values())
    assert len({next(iter(v)) for v in pairs.values()}) == 6


def test_product_vq_bad_groups():
    p = QuantizerParams(method="product_vq", group_codes=(3, 2))
    with pytest.raises(ParamError, match="groups"):
        make_quantizer(p, 3)
    with pytest.raises(ParamError, match="summing"):
        make_quantizer(p, 3, groups=(1, 1))
    with pytest.raises(ParamError, match="2 entries"):
        make_quantizer(p, 3, groups=(1, 1, 1))
    with pytest.raises(ParamError, match="group_codes"):
        make_quantizer(QuantizerParams(method="product_vq"), 3, groups=(3,))


def test_component_weights_decide_what_kmeans_splits():
    """Two tight clusters along x0 and a wide uniform nuisance along x1 (same z-scored
    spread): with 2 codes, weights (1, 1e-3) split exactly along x0 (the clusters), weights
    (1e-3, 1) along x1; the fitted scale is std / weight (analytic)."""
    rng = np.random.default_rng(0)
    n = 2000
    side = rng.integers(0, 2, n) * 2 - 1
    x = np.stack([side + 0.01 * rng.normal(size=n), rng.uniform(-3, 3, n)], 1)
    p = QuantizerParams(method="vq", num_codes=2, kmeans_iters=30)
    key = jax.random.PRNGKey(1)
    qz = fit_quantizer(key, x, p, weights=jnp.array([1.0, 1e-3]))
    idx = np.asarray(quantize(qz, x))
    assert len(set(idx[side > 0])) == 1 and len(set(idx[side < 0])) == 1
    assert idx[side > 0][0] != idx[side < 0][0]
    np.testing.assert_allclose(np.asarray(qz.scale), x.std(0) / np.array([1.0, 1e-3]),
                               rtol=1e-4)
    qz2 = fit_quantizer(key, x, p, weights=jnp.array([1e-3, 1.0]))
    idx2 = np.asarray(quantize(qz2, x))
    a = idx2[x[:, 1] > 0.5]
    b = idx2[x[:, 1] < -0.5]
    assert len(set(a)) == 1 and len(set(b)) == 1 and a[0] != b[0]
    # product VQ: the weights act inside each group
    pq = QuantizerParams(method="product_vq", group_codes=(2, 1), kmeans_iters=30)
    qz3 = fit_quantizer(key, x, pq, groups=(1, 1), weights=jnp.array([1.0, 1.0]))
    qz4 = fit_quantizer(key, x, pq, groups=(1, 1))
    np.testing.assert_array_equal(np.asarray(quantize(qz3, x)), np.asarray(quantize(qz4, x)))
    with pytest.raises(ParamError, match="weights must have shape"):
        fit_quantizer(key, x, p, weights=jnp.ones(3))
