"""vbl.draws against jax.random (the peer it mirrors) and against the uniform law."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vbl.draws import (
    Words,
    check_switched_off,
    draw_blocks,
    normal,
    randint,
    uniform01,
    uniform_pm1,
)
from vbl.params import ParamError


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


def test_draw_blocks_are_the_whole_layouts_words_whichever_are_on():
    """Block j is ``jax.random.bits(key, (W,))[s_j:s_j + n_j]`` whether or not the other
    blocks are drawn; a block that is off is None; typed and raw keys, under vmap."""
    sizes = (3, 5, 1, 12)
    total = sum(sizes)
    starts = np.cumsum((0,) + sizes[:-1])
    for key in (jax.random.key(11), jax.random.PRNGKey(4)):
        full = np.asarray(jax.random.bits(key, (total,), jnp.uint32))
        for mask in range(16):
            on = [bool(mask >> j & 1) for j in range(4)]
            blocks = draw_blocks(key, *zip(sizes, on, strict=True))
            for j, b in enumerate(blocks):
                if on[j]:
                    np.testing.assert_array_equal(np.asarray(b),
                                                  full[starts[j]:starts[j] + sizes[j]])
                else:
                    assert b is None
    keys = jax.random.split(jax.random.key(2), 6)
    got = jax.jit(jax.vmap(lambda k: draw_blocks(k, (4, False), 3)[1]))(keys)
    want = jax.vmap(lambda k: jax.random.bits(k, (7,), jnp.uint32))(keys)[:, 4:]
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_draw_blocks_hashes_only_the_blocks_that_are_on():
    def hashed(*blocks):
        jaxpr = jax.make_jaxpr(lambda k: draw_blocks(k, *blocks))(jax.random.key(0)).jaxpr
        return sum(int(np.prod(e.outvars[0].aval.shape)) for e in jaxpr.eqns
                   if e.primitive.name == "threefry2x32")

    assert hashed(3, (5, False), 12) == 15
    assert hashed((5, False)) == 0
    assert hashed(2, (0, True), 4) == 6


def test_check_switched_off_names_the_switch():
    check_switched_off(False, "noise_on.x", {"a.std": 0.0, "b.std": np.zeros(3)})
    check_switched_off(True, "noise_on.x", {"a.std": 1.0})
    with pytest.raises(ParamError, match=r"b.std=.* noise_on.x is False"):
        check_switched_off(False, "noise_on.x", {"a.std": 0.0, "b.std": np.array([0.0, 2.0])})
