"""Random numbers from one hash: uniform and normal floats sliced from a block of bits.

Hashing dominates the random numbers of an env step on CPU: every ``jax.random.split``,
``uniform`` or ``normal`` call is one threefry evaluation. An env step therefore draws all
its random numbers at once, ``words = jax.random.bits(key, (W,), uint32)`` (one hash per env
and primitive), and converts slices of the words with the functions below. They map a word
to a float exactly as ``jax.random.uniform`` / ``jax.random.normal`` map theirs (23 mantissa
bits; normals by the inverse error function), so the distributions are the same.

:class:`Words` hands out consecutive slices by count, so a caller states how many numbers
each consumer takes and the layout cannot overlap.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Words", "uniform01", "uniform_pm1", "normal", "uniform_index", "randint"]

F32 = jnp.float32
_SQRT2 = np.float32(np.sqrt(2.0))
_LO = np.nextafter(np.float32(-1.0), np.float32(0.0))  # (-1, 1): erfinv stays finite


def uniform01(words: jax.Array) -> jax.Array:
    """uint32 words (...) -> float32 uniform in [0, 1) (the 23 high bits as the mantissa)."""
    bits = (jnp.asarray(words, jnp.uint32) >> 9) | np.uint32(0x3F800000)
    return jax.lax.bitcast_convert_type(bits, F32) - np.float32(1.0)


def uniform_pm1(words: jax.Array) -> jax.Array:
    """uint32 words (...) -> float32 uniform in (-1, 1) (as ``jax.random.uniform(key, shape,
    float32, nextafter(-1, 0), 1)``)."""
    return jnp.maximum(_LO, uniform01(words) * (np.float32(1.0) - _LO) + _LO)


def normal(words: jax.Array) -> jax.Array:
    """uint32 words (...) -> float32 standard normal (``sqrt(2) erfinv(u)``, u in (-1, 1))."""
    return _SQRT2 * jax.lax.erf_inv(uniform_pm1(words))


def uniform_index(u: jax.Array, n) -> jax.Array:
    """float32 uniform draws ``u`` (...) in [0, 1) -> int32 uniform in [0, n) (``n`` >= 1, may
    be traced; floor of ``u n``: bias below 2**-23 relative for the small ranges used here)."""
    n = jnp.asarray(n, jnp.int32)
    k = jnp.floor(jnp.asarray(u, F32) * n.astype(F32)).astype(jnp.int32)
    return jnp.minimum(k, jnp.maximum(n - 1, 0))


def randint(words: jax.Array, low, high) -> jax.Array:
    """uint32 words (...) -> int32 uniform in [low, high) (``high - low`` >= 1, may be traced;
    :func:`uniform_index` of :func:`uniform01`)."""
    low = jnp.asarray(low, jnp.int32)
    return low + uniform_index(uniform01(words), jnp.asarray(high, jnp.int32) - low)


class Words:
    """Consecutive slices of one block of random words: ``take(n)`` returns the next n.

    Build it with :meth:`draw` (one hash) for a known total, e.g.::

        w = Words.draw(key, 14)
        starts = uniform01(w.take(12)); delay = randint(w.take(1)[0], 0, 16)

    ``done()`` checks that every word was used (a layout error otherwise).
    """

    def __init__(self, words: jax.Array):
        self._words = words
        self._next = 0

    @classmethod
    def draw(cls, key: jax.Array, count: int) -> Words:
        """``count`` words from one threefry evaluation of ``key`` (none for 0)."""
        if int(count) == 0:
            return cls(jnp.zeros((0,), jnp.uint32))
        return cls(jax.random.bits(key, (int(count),), jnp.uint32))

    def take(self, n: int) -> jax.Array:
        """The next ``n`` words, (n,) uint32."""
        n = int(n)
        if self._next + n > self._words.shape[0]:
            raise ValueError(f"random words exhausted: {self._words.shape[0]} drawn, "
                             f"{self._next + n} needed")
        out = self._words[self._next:self._next + n]
        self._next += n
        return out

    def done(self) -> None:
        """Raise ValueError unless every drawn word was taken."""
        if self._next != self._words.shape[0]:
            raise ValueError(f"{self._words.shape[0]} random words drawn, {self._next} used")
