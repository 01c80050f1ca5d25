"""Random numbers from one hash: uniform and normal floats sliced from a block of bits.

Hashing dominates the random numbers of an env step on CPU: every ``jax.random.split``,
``uniform`` or ``normal`` call is one threefry evaluation. An env step therefore draws all
its random numbers at once (one hash per env and primitive) and converts slices of the
words with the functions below. They map a word to a float exactly as
``jax.random.uniform`` / ``jax.random.normal`` map theirs (23 mantissa bits; normals by the
inverse error function), so the distributions are the same.

:func:`draw_blocks` lays the words of one call out in consecutive blocks, one per consumer,
and hashes only the blocks that are switched on: word ``i`` of the layout is
``jax.random.bits(key, (W,), uint32)[i]`` whichever blocks are on, so switching a noise
source off removes its hashing and leaves every other draw unchanged. :class:`Words` hands
out consecutive slices of one block by count, so the layout cannot overlap.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.random import threefry2x32_p

from vbl.params import ParamError

__all__ = ["Words", "draw_blocks", "check_switched_off", "uniform01", "uniform_pm1", "normal",
           "normals", "uniform_index", "randint"]

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


def normals(words: jax.Array | None) -> jax.Array | None:
    """:func:`normal` of a block of :func:`draw_blocks`; None (a block switched off) stays
    None."""
    return None if words is None else normal(words)


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


def _as_typed_key(key: jax.Array) -> jax.Array:
    """A typed PRNG key for ``key`` (a raw uint32 key gets the default implementation, as
    ``jax.random.bits`` gives it)."""
    if jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        return key
    return jax.random.wrap_key_data(key)


def _bits_at(key: jax.Array, positions: np.ndarray, total: int) -> jax.Array:
    """``jax.random.bits(key, (total,), uint32)[positions]``, hashing only ``positions``.

    With jax's partitionable threefry (the default since jax 0.5) word ``i`` is the hash of
    the counter ``i`` alone, so the selected counters are hashed directly (one threefry
    evaluation of ``len(positions)`` counters); otherwise all ``total`` words are drawn and
    gathered.
    """
    key = _as_typed_key(key)
    if jax.config.jax_threefry_partitionable and str(jax.random.key_impl(key)) == "threefry2x32":
        kd = jax.random.key_data(key)
        lo = jnp.asarray(positions, jnp.uint32)
        b1, b2 = threefry2x32_p.bind(kd[..., 0], kd[..., 1], jnp.zeros_like(lo), lo)
        return b1 ^ b2
    return jax.random.bits(key, (total,), jnp.uint32)[positions]


def draw_blocks(key: jax.Array, *blocks: int | tuple[int, bool]) -> list[jax.Array | None]:
    """Random words of consecutive blocks of one layout, hashing only the blocks that are on.

    Each block is ``n`` (on) or ``(n, on)`` with ``on`` a Python bool (static: a switched-off
    block costs nothing in the compiled program). Block ``j`` covers the words
    ``[s_j, s_j + n_j)`` of ``jax.random.bits(key, (W,), uint32)``, where ``s_j`` sums the sizes
    of the blocks before it, on or off, and ``W`` of all: a block's words do not depend on
    which other blocks are on. Returns one (n_j,) uint32 array per block that is on (all
    from one threefry evaluation) and None per block that is off.
    """
    sizes, ons = [], []
    for b in blocks:
        n, on = (b, True) if isinstance(b, int | np.integer) else b
        if int(n) < 0:
            raise ValueError(f"a block of {n} words: sizes must be >= 0")
        sizes.append(int(n))
        ons.append(bool(on))
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    positions = np.concatenate([np.arange(starts[j], starts[j + 1]) for j in range(len(sizes))
                                if ons[j]] + [np.zeros(0, np.int64)])
    words = (_bits_at(key, positions.astype(np.uint32), int(starts[-1])) if positions.size
             else jnp.zeros((0,), jnp.uint32))
    out, at = [], 0
    for n, on in zip(sizes, ons, strict=True):
        out.append(words[at:at + n] if on else None)
        at += n if on else 0
    return out


def check_switched_off(on: bool, switch: str, stds: dict[str, Any]) -> None:
    """Raise ParamError if a noise source's static switch ``switch`` is off while one of its
    ``stds`` ({parameter path: value}, numbers or arrays) is not 0: the noise would be
    silently missing."""
    if on:
        return
    for path, value in stds.items():
        if np.any(np.asarray(value) != 0):
            raise ParamError(f"{path}={value!r} needs random draws, but {switch} is False "
                             f"(a static switch: noise that is off is not computed); set "
                             f"{switch}=True, or {path}=0")


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
        """``count`` words from one threefry evaluation of ``key`` (none for 0):
        ``jax.random.bits(key, (count,), uint32)``."""
        return cls(draw_blocks(key, int(count))[0])

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
