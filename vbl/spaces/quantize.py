"""Continuous state vectors -> Q-table indices (the quantiser of the Figure 11 pipeline).

Two methods, chosen by the static :attr:`QuantizerParams.method`:

* ``"bins"``: each of the ``d`` components is cut into ``bins`` equal-width bins over a range
  fitted to collected states (the ``range_quantile`` and ``1 - range_quantile`` quantiles of
  each component, so a few outliers do not stretch the grid); values outside the range fall
  into the edge bins. Index = mixed-radix number of the per-component bins, ``bins ** d``
  states.
* ``"vq"``: vector quantisation. The components are z-scored with their fitted mean and
  standard deviation, then a codebook of ``num_codes`` vectors is fitted by k-means (k-means++
  seeding, Lloyd iterations, all in JAX); the index of a state is its nearest code
  (Euclidean, in z-scored units). ``num_codes`` states.
* ``"product_vq"``: one such codebook per group of consecutive components (the caller says
  which, e.g. one group per observed object: :mod:`vbl.agents.cva_state`), ``group_codes[g]``
  codes for group ``g``; index = mixed-radix number of the per-group codes (group 0 fastest),
  ``prod(group_codes)`` states. k-means cannot then spend one object's resolution on
  another's: every group keeps its own number of cells.

Everything is pure JAX on pytrees: :func:`fit_quantizer` and :func:`quantize` can be
``jit``-ed and ``vmap``-ed over learners (the fitted :class:`Quantizer` is a pytree whose
static fields are the method and the sizes).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import ParamError, param, validate

__all__ = [
    "QUANTIZE_METHODS",
    "QuantizerParams",
    "Quantizer",
    "num_states",
    "fit_quantizer",
    "quantize",
    "nearest",
    "kmeans",
    "kmeans_plus_plus",
    "distortion",
    "make_quantizer",
]

#: State-to-index methods (static choice).
QUANTIZE_METHODS = ("bins", "vq", "product_vq")


@struct.dataclass
class QuantizerParams:
    """How a continuous state vector becomes a Q-table index."""

    method: str = param("vq", doc="'bins': uniform bins per component (bins**d states); "
                        "'vq': k-means codebook on z-scored vectors (num_codes states)",
                        static=True, choices=QUANTIZE_METHODS)
    bins: int = param(4, doc="bins per component (method 'bins')", static=True, ge=1)
    num_codes: int = param(128, doc="codebook size = number of states (method 'vq')",
                           static=True, ge=1)
    group_codes: tuple = param((), doc="method 'product_vq': codebook size of each group of "
                               "components (groups given by the caller, e.g. one per observed "
                               "object); states = the product", static=True)
    kmeans_iters: int = param(30, doc="Lloyd iterations of the k-means fit (methods 'vq', "
                              "'product_vq')", static=True, ge=0)
    range_quantile: float = param(0.01, doc="method 'bins': the fitted range of a component "
                                  "is its [q, 1-q] quantile interval over the collected states",
                                  ge=0.0, lt=0.5)
    max_states: int = param(2_000_000, doc="refuse quantisers with more states than this "
                            "(a Q-table row per state)", static=True, ge=1)

    def check(self) -> None:
        if self.method == "product_vq":
            if not self.group_codes:
                raise ParamError("method 'product_vq' needs group_codes (one codebook size per "
                                 "group of components), got ()")
            if not all(isinstance(k, int | np.integer) and not isinstance(k, bool) and k >= 1
                       for k in self.group_codes):
                raise ParamError(f"group_codes={self.group_codes!r} must hold integers >= 1")


@struct.dataclass
class Quantizer:
    """A fitted quantiser for ``d``-dimensional vectors (a pytree; vmappable over learners).

    Attributes:
      lo, hi: float32 (d,), the fitted per-component range (method 'bins').
      mean, scale: float32 (d,), z-scoring used before the codebook (methods 'vq',
        'product_vq'; scale = std / component weight).
      codebook: float32 (K, d) in z-scored units (method 'vq'; (1, d) zeros for 'bins';
        'product_vq': the groups' codebooks stacked, (sum group_codes, d), each row zero
        outside its group's components).
      method, bins, group_codes: static copies of the parameters; groups: static sizes of
        the component groups ('product_vq').
    """

    lo: jax.Array
    hi: jax.Array
    mean: jax.Array
    scale: jax.Array
    codebook: jax.Array
    method: str = struct.field(pytree_node=False, default="vq")
    bins: int = struct.field(pytree_node=False, default=4)
    groups: tuple = struct.field(pytree_node=False, default=())
    group_codes: tuple = struct.field(pytree_node=False, default=())

    @property
    def dim(self) -> int:
        return int(self.lo.shape[-1])

    @property
    def num_states(self) -> int:
        if self.method == "bins":
            return int(self.bins) ** self.dim
        if self.method == "product_vq":
            return int(np.prod(self.group_codes))
        return int(self.codebook.shape[-2])


def num_states(params: QuantizerParams, dim: int) -> int:
    """Number of discrete states (Q-table rows) a quantiser of ``dim``-vectors produces."""
    if params.method == "bins":
        return int(params.bins) ** int(dim)
    if params.method == "vq":
        return int(params.num_codes)
    if params.method == "product_vq":
        return int(np.prod([int(k) for k in params.group_codes])) if params.group_codes else 0
    raise ParamError(f"quantizer method {params.method!r} unknown; choose one of "
                     f"{list(QUANTIZE_METHODS)}")


def make_quantizer(params: QuantizerParams, dim: int,
                   groups: tuple[int, ...] | None = None) -> QuantizerParams:
    """Validate ``params`` for ``dim``-vectors (non-jitted entry point); returns ``params``.
    ``groups``: sizes of the consecutive component groups (method 'product_vq')."""
    validate(params)
    if not isinstance(dim, int | np.integer) or dim < 1:
        raise ParamError(f"state dimension must be an int >= 1, got {dim!r}")
    if params.method == "product_vq":
        _check_groups(params, dim, groups)
    s = num_states(params, dim)
    if s > params.max_states:
        raise ParamError(f"quantizer {params.method!r} on {dim}-vectors gives {s} states, more "
                         f"than max_states={params.max_states}; use fewer bins, fewer "
                         "components or method 'vq'")
    return params


def _check_groups(params: QuantizerParams, dim: int, groups) -> tuple[int, ...]:
    if groups is None or not len(groups):
        raise ParamError("method 'product_vq' needs the component groups (sizes summing to the "
                         f"state dimension {dim})")
    groups = tuple(int(g) for g in groups)
    if any(g < 1 for g in groups) or sum(groups) != dim:
        raise ParamError(f"component groups {groups} must be sizes >= 1 summing to the state "
                         f"dimension {dim}")
    if len(params.group_codes) != len(groups):
        raise ParamError(f"group_codes={params.group_codes!r} has {len(params.group_codes)} "
                         f"entries but the state vector has {len(groups)} groups {groups}")
    return groups


#: Smallest component weight of :func:`fit_quantizer` (a weight of 0 would divide by 0).
MIN_COMPONENT_WEIGHT = 1e-3

# --------------------------------------------------------------------------- k-means


def _sq_dists(x: jax.Array, c: jax.Array) -> jax.Array:
    """Squared Euclidean distances (N, K) between rows of x (N, d) and c (K, d)."""
    x2 = jnp.sum(x * x, axis=-1, keepdims=True)
    c2 = jnp.sum(c * c, axis=-1)
    return jnp.maximum(x2 - 2.0 * x @ c.T + c2[None, :], 0.0)


def nearest(d: jax.Array) -> jax.Array:
    """Index int32 (N,) of the smallest of each row of distances ``d`` (N, K), ties and NaN
    as ``jnp.argmin`` (the first minimum; a row with NaN: its first NaN).

    Two plain reductions (the minimum, then the first index that attains it) instead of
    one over (value, index) pairs, which XLA's CPU backend does not vectorise
    (docs/findings/learner_cost.md, "Nearest code"). ``d`` is materialised once
    (``optimization_barrier``), so both reductions read the same values (a copy of its
    computation fused into each could round differently and miss the minimum).
    """
    d = jax.lax.optimization_barrier(d)
    hit = (d == jnp.min(d, axis=-1, keepdims=True)) | jnp.isnan(d)
    k = d.shape[-1]
    return jnp.min(jnp.where(hit, jnp.arange(k, dtype=jnp.int32), k), axis=-1)


def distortion(x: jax.Array, codebook: jax.Array, weights: jax.Array | None = None) -> jax.Array:
    """Mean squared distance of the rows of ``x`` (N, d) to their nearest code (K, d)."""
    d = jnp.min(_sq_dists(x, codebook), axis=-1)
    w = jnp.ones(d.shape, d.dtype) if weights is None else weights.astype(d.dtype)
    return jnp.sum(w * d) / jnp.maximum(jnp.sum(w), 1e-12)


def kmeans_plus_plus(key: jax.Array, x: jax.Array, k: int,
                     weights: jax.Array | None = None) -> jax.Array:
    """k-means++ seeding: ``k`` rows of ``x`` (N, d), each drawn with probability proportional
    to weight x squared distance to the codes drawn so far. Returns (k, d)."""
    n = x.shape[0]
    w = jnp.ones((n,), x.dtype) if weights is None else weights.astype(x.dtype)
    keys = jax.random.split(key, k)
    first = jax.random.categorical(keys[0], jnp.log(jnp.maximum(w, 1e-30)))
    codes = jnp.zeros((k, x.shape[1]), x.dtype).at[0].set(x[first])
    d0 = jnp.sum((x - x[first]) ** 2, axis=-1)

    def body(i, carry):
        codes, dmin = carry
        p = w * dmin
        # all-zero distances (fewer distinct points than k): fall back to the weights
        logits = jnp.where(jnp.sum(p) > 0, jnp.log(jnp.maximum(p, 1e-30)),
                           jnp.log(jnp.maximum(w, 1e-30)))
        j = jax.random.categorical(keys[i], logits)
        codes = codes.at[i].set(x[j])
        dmin = jnp.minimum(dmin, jnp.sum((x - x[j]) ** 2, axis=-1))
        return codes, dmin

    codes, _ = jax.lax.fori_loop(1, k, body, (codes, d0))
    return codes


def kmeans(key: jax.Array, x: jax.Array, k: int, iters: int,
           weights: jax.Array | None = None, init: jax.Array | None = None) -> jax.Array:
    """Weighted k-means (Lloyd) on ``x`` (N, d); returns the codebook (k, d).

    Seeded by :func:`kmeans_plus_plus` unless ``init`` (k, d) is given. A code that loses
    all its points keeps its previous position. ``weights`` (N,) >= 0 (e.g. a 0/1 mask of
    valid samples). ``k`` and ``iters`` are static Python ints.
    """
    x = jnp.asarray(x)
    w = jnp.ones((x.shape[0],), x.dtype) if weights is None else weights.astype(x.dtype)
    codes = kmeans_plus_plus(key, x, k, w) if init is None else jnp.asarray(init, x.dtype)

    def lloyd(_, codes):
        assign = nearest(_sq_dists(x, codes))
        onehot = jax.nn.one_hot(assign, k, dtype=x.dtype) * w[:, None]  # (N, k)
        counts = jnp.sum(onehot, axis=0)
        sums = onehot.T @ x
        new = sums / jnp.maximum(counts, 1e-12)[:, None]
        return jnp.where(counts[:, None] > 0, new, codes)

    return jax.lax.fori_loop(0, iters, lloyd, codes)


# --------------------------------------------------------------------------- fit / apply


def fit_quantizer(key: jax.Array, x: jax.Array, params: QuantizerParams,
                  mask: jax.Array | None = None,
                  groups: tuple[int, ...] | None = None,
                  weights: jax.Array | None = None) -> Quantizer:
    """Fit a quantiser to collected states ``x`` (N, d) (rows with ``mask`` False ignored).
    ``groups`` (static sizes of consecutive component groups) is needed by 'product_vq'.
    ``weights`` (d,) > 0 (methods 'vq', 'product_vq'): each z-scored component is multiplied
    by its weight before k-means and before the nearest-code search (folded into ``scale``),
    so its differences count w times (weights below ``MIN_COMPONENT_WEIGHT`` are raised to
    it); e.g. canonical correlations, which make the distance that of the predicted future
    (:mod:`vbl.agents.cva_state`).

    Pure and jit/vmap-able (``params`` static fields set shapes). float32 throughout.
    """
    x = jnp.asarray(x, jnp.float32)
    n, d = x.shape
    m = jnp.ones((n,), bool) if mask is None else jnp.asarray(mask, bool)
    w = m.astype(jnp.float32)
    wsum = jnp.maximum(jnp.sum(w), 1.0)
    mean = jnp.sum(w[:, None] * x, axis=0) / wsum
    var = jnp.sum(w[:, None] * (x - mean) ** 2, axis=0) / wsum
    scale = jnp.where(var > 0, jnp.sqrt(var), 1.0).astype(jnp.float32)
    if weights is not None:
        if jnp.shape(weights) not in ((), (d,)):
            raise ParamError(f"weights must have shape ({d},) (one per component) or be a "
                             f"scalar, got shape {jnp.shape(weights)}")
        wt = jnp.broadcast_to(jnp.asarray(weights, jnp.float32), (d,))
        scale = scale / jnp.maximum(wt, MIN_COMPONENT_WEIGHT)
    xm = jnp.where(m[:, None], x, jnp.nan)
    q = jnp.asarray(params.range_quantile, jnp.float32)
    lo = jnp.nanquantile(xm, q, axis=0).astype(jnp.float32)
    hi = jnp.nanquantile(xm, 1.0 - q, axis=0).astype(jnp.float32)
    hi = jnp.where(hi > lo, hi, lo + 1.0)  # a constant component: one bin holds everything
    if params.method == "vq":
        z = (x - mean) / scale
        codebook = kmeans(key, z, params.num_codes, params.kmeans_iters, weights=w)
    elif params.method == "product_vq":
        groups = _check_groups(params, d, groups)
        z = (x - mean) / scale
        books, start = [], 0
        for g, (size, k) in enumerate(zip(groups, params.group_codes, strict=True)):
            sub = kmeans(jax.random.fold_in(key, g), z[:, start:start + size], int(k),
                         params.kmeans_iters, weights=w)
            books.append(jnp.pad(sub, ((0, 0), (start, d - start - size))))
            start += size
        codebook = jnp.concatenate(books, axis=0)
    elif params.method == "bins":
        codebook = jnp.zeros((1, d), jnp.float32)
    else:
        raise ParamError(f"quantizer method {params.method!r} unknown; choose one of "
                         f"{list(QUANTIZE_METHODS)}")
    prod = params.method == "product_vq"
    return Quantizer(lo=lo, hi=hi, mean=mean.astype(jnp.float32), scale=scale,
                     codebook=codebook.astype(jnp.float32), method=params.method,
                     bins=params.bins, groups=tuple(groups) if prod else (),
                     group_codes=tuple(int(k) for k in params.group_codes) if prod else ())


def bin_indices(qz: Quantizer, x: jax.Array) -> jax.Array:
    """Per-component bin numbers int32 (..., d) in [0, bins) (method 'bins')."""
    x = jnp.asarray(x, jnp.float32)
    frac = (x - qz.lo) / (qz.hi - qz.lo)
    return jnp.clip(jnp.floor(frac * qz.bins), 0, qz.bins - 1).astype(jnp.int32)


def quantize(qz: Quantizer, x: Any) -> jax.Array:
    """State index int32 (...) in [0, num_states) of vectors ``x`` (..., d).

    'bins': mixed-radix number sum_j b_j * bins**j (component 0 is the fastest digit).
    'vq': index of the nearest code in z-scored units (ties: lowest index).
    'product_vq': mixed-radix number of each group's nearest code (group 0 fastest).
    """
    x = jnp.asarray(x, jnp.float32)
    if qz.method == "bins":
        b = bin_indices(qz, x)
        radix = (qz.bins ** jnp.arange(qz.dim, dtype=jnp.int32)).astype(jnp.int32)
        return jnp.sum(b * radix, axis=-1).astype(jnp.int32)
    z = (x - qz.mean) / qz.scale
    lead = z.shape[:-1]
    if qz.method == "product_vq":
        flat = z.reshape(-1, qz.dim)
        index, start, row, radix = jnp.zeros(flat.shape[0], jnp.int32), 0, 0, 1
        for size, k in zip(qz.groups, qz.group_codes, strict=True):
            book = qz.codebook[row:row + k, start:start + size]
            code = nearest(_sq_dists(flat[:, start:start + size], book))
            index = index + radix * code
            start, row, radix = start + size, row + k, radix * k
        return index.reshape(lead)
    d = _sq_dists(z.reshape(-1, qz.dim), qz.codebook)
    return nearest(d).reshape(lead)
