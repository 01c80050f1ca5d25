"""vbl.draws against jax.random (the peer it mirrors) and against the uniform law."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.draws import Words, normal, randint, uniform01, uniform_pm1


def _bits(seed, n):
    return jax.random.bits(jax.random.key(seed), (n,), jnp.uint32)


def test_uniform_equals_jax_random_uniform():
    key = jax.random.key(3)
    ours = uniform01(jax.random.bits(key, (4096,), jnp.uint32))
    theirs = jax.random.uniform(key, (4096,), jnp.float32)
    np.testing.assert_array_equal(np.asarray(ours), np.asarray(theirs))


def test_normal_equals_jax_random_normal():
    key = jax.random.key(5)
    ours = normal(jax.random.bits(key, (4096,), jnp.uint32))
    theirs = jax.random.normal(key, (4096,), jnp.float32)
    np.testing.assert_allclose(np.asarray(ours), np.asarray(theirs), rtol=1e-6, atol=1e-6)


def test_extreme_words_stay_finite_and_in_range():
    words = jnp.array([0, 1, 2**9 - 1, 2**31, 2**32 - 2**9, 2**32 - 1], jnp.uint32)
    u = np.asarray(uniform01(words))
    assert np.all((u >= 0) & (u < 1))
    v = np.asarray(uniform_pm1(words))
    assert np.all((v > -1) & (v < 1))
    assert np.all(np.isfinite(np.asarray(normal(words))))


def test_randint_is_uniform_on_its_range():
    n, lo, hi = 64_000, 3, 19
    k = np.asarray(randint(_bits(7, n), lo, hi))
    assert k.min() == lo and k.max() == hi - 1
    counts = np.bincount(k - lo, minlength=hi - lo)
    expected = n / (hi - lo)
    chi2 = np.sum((counts - expected) ** 2 / expected)
    assert chi2 < 45.0  # 15 degrees of freedom: P(chi2 > 45) ~ 1e-4


def test_randint_single_value_range():
    assert np.all(np.asarray(randint(_bits(1, 100), 4, 5)) == 4)


def test_words_slices_in_order_and_checks_the_layout():
    raw = _bits(9, 5)
    w = Words(raw)
    np.testing.assert_array_equal(np.asarray(w.take(2)), np.asarray(raw[:2]))
    np.testing.assert_array_equal(np.asarray(w.take(3)), np.asarray(raw[2:]))
    w.done()
    with pytest.raises(ValueError, match="exhausted"):
        w.take(1)
    w2 = Words.draw(jax.random.key(0), 4)
    w2.take(3)
    with pytest.raises(ValueError, match="4 random words drawn, 3 used"):
        w2.done()
    Words.draw(jax.random.key(0), 0).done()
