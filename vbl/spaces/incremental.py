"""On-line, incremental state-space segmentation (paper Section 2.2): the partition.

A state is a box of a partition of the normalised feature cube [0, 1]^D into axis-aligned
boxes (the leaves of a binary tree of splits, stored flat as ``lo``, ``hi`` (L, D) and
``active`` (L,)); :func:`leaf_of` classifies by one vectorised box test. :func:`record`
puts transitions ``(x, a, y)``, ``y = (x' - x, scored)``, into a ring buffer;
:func:`structure_update` refits an affine ridge model per box and primitive from the
buffer and splits the box whose model error (or, with ``value_split_gain > 0``, whose
greedy value, :func:`td_targets`) a cut reduces most, else merges two adjacent boxes that
one model explains; the Q table (L, A) goes in and comes back with the new boxes' rows.
The learner on top is :mod:`vbl.agents.segmentation_learner`.

See docs/state_spaces.md, "On-line: incremental segmentation" (criteria, thresholds, cost).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import ParamError, param

__all__ = [
    "SegmentationParams",
    "Segmentation",
    "Buffer",
    "init_segmentation",
    "init_buffer",
    "leaf_of",
    "num_states",
    "record",
    "structure_update",
    "td_targets",
]

F32 = jnp.float32
F64 = jnp.float64
I32 = jnp.int32


def _require_x64() -> None:
    """The local-model statistics are float64: refuse to trace them with 64-bit types off
    (JAX would silently compute them in float32)."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError("the on-line learner's statistics need 64-bit types: call it "
                           "inside `with jax.enable_x64(True):` (the engine runs every "
                           "experiment so)")


@struct.dataclass
class SegmentationParams:
    """Segmentation thresholds (normalised feature units) and the Q-values of new boxes."""

    max_states: int = param(64, doc="capacity: most boxes (states, the goal not counted)",
                            static=True, ge=1)
    bins: int = param(4, doc="candidate cuts per axis: bin edges of this many equal bins",
                      static=True, ge=2)
    buffer_size: int = param(2048, doc="transitions kept for the local models (most recent)",
                             static=True, ge=8)
    update_every: int = param(100, doc="steps between model refits / split / merge",
                              unit="steps", static=True, ge=1)
    split_error: float = param(1e-2, doc="a box may split when its model residual per "
                               "transition exceeds this", unit="(norm. units)^2", gt=0.0)
    split_gain: float = param(3e-3, doc="least residual reduction per transition of a split",
                              unit="(norm. units)^2", gt=0.0)
    merge_tol: float = param(5e-4, doc="merge two boxes when their joint model raises the "
                             "residual per transition by at most this (< split_gain)",
                             unit="(norm. units)^2", ge=0.0)
    min_samples: float = param(50.0, doc="least transitions on each side of a split / in "
                               "each box of a merge", ge=1.0)
    min_width: float = param(1.0 / 64, doc="narrowest box side a split may create",
                             unit="norm. units", gt=0.0, lt=0.5)
    outcome_weight: float = param(0.1, doc="weight of the 'scored' output in the residual "
                                  "(outcome disagreement)", ge=0.0)
    ridge: float = param(1e-4, doc="ridge of the least-squares fits", gt=0.0)
    inherit_q: bool = param(True, doc="a new box starts from its parent's Q-values (else "
                            "q_init)")
    q_init: float = param(0.0, doc="initial Q-value of new boxes (inherit_q off, and at "
                          "start)")
    discount: float = param(0.95, doc="discount per action (state change): TD targets of the "
                         "value-driven splits and the one-step Q-learning update", ge=0.0, lt=1.0)
    split_candidates: int = param(8, doc="boxes (largest residual per transition) whose cuts "
                                  "are evaluated at each update", static=True, ge=1)
    value_split_gain: float = param(0.06, doc="value-driven splits: least gain per transition "
                                    "of a cut in the value of acting greedily on each side "
                                    "separately over acting greedily in the whole box, from "
                                    "TD targets of the buffered transitions (0: off, only "
                                    "model-error splits)", unit="Q units", ge=0.0)
    value_min_count: float = param(20.0, doc="value-driven splits: least transitions of a "
                                   "primitive on a side (in a box) for its mean TD target to "
                                   "enter that side's (box's) greedy value", ge=1.0)
    value_crossfit: bool = param(True, doc="value-driven splits: each side's greedy primitive "
                                 "is chosen on one half of the buffer and valued on the other "
                                 "(cross-fitting: no gain from noise alone in expectation); "
                                 "else max of the means (biased upwards on small sides)")
    value_merge_tol: float = param(0.005, doc="with value-driven splits on, two boxes merge only "
                                   "if acting greedily in each separately beats acting greedily "
                                   "in their union by at most this per transition "
                                   "(< value_split_gain: hysteresis)", unit="Q units", ge=0.0)

    def check(self) -> None:
        if np.any(np.asarray(self.merge_tol) >= np.asarray(self.split_gain)):
            raise ParamError(f"merge_tol={self.merge_tol} must be < split_gain="
                             f"{self.split_gain} (else a split is undone at once)")
        if np.any(np.asarray(self.split_gain) > np.asarray(self.split_error)):
            raise ParamError(f"split_gain={self.split_gain} must be <= split_error="
                             f"{self.split_error}")
        on = np.asarray(self.value_split_gain) > 0
        if np.any(on & (np.asarray(self.value_merge_tol) >= np.asarray(self.value_split_gain))):
            raise ParamError(f"value_merge_tol={self.value_merge_tol} must be < "
                             f"value_split_gain={self.value_split_gain} when value-driven "
                             "splits are on (else a value split is undone at once)")


@struct.dataclass
class Segmentation:
    """Boxes: lo, hi (L, D) float32 corners; active (L,) bool."""

    lo: jax.Array
    hi: jax.Array
    active: jax.Array


@struct.dataclass
class Buffer:
    """Ring buffer: x (M, D) float32, a (M,) int32, y (M, D+1) float32 (change of x,
    scored), valid (M,) bool, ptr () int32 next slot, clock (M,) int32 the learner's
    primitive count at the write, term (M,) bool the transition ended its episode (goal or
    failure; not a time-limit truncation)."""

    x: jax.Array
    a: jax.Array
    y: jax.Array
    valid: jax.Array
    ptr: jax.Array
    clock: jax.Array
    term: jax.Array


def init_segmentation(p: SegmentationParams, dim: int) -> Segmentation:
    """One box covering [0, 1]^dim (capacity ``max_states``)."""
    cap = p.max_states
    return Segmentation(lo=jnp.zeros((cap, dim), F32),
                        hi=jnp.zeros((cap, dim), F32).at[0].set(1.0),
                        active=jnp.zeros((cap,), bool).at[0].set(True))


def init_buffer(p: SegmentationParams, dim: int) -> Buffer:
    """An empty ring buffer of ``buffer_size`` transitions."""
    m = p.buffer_size
    return Buffer(x=jnp.zeros((m, dim), F32), a=jnp.zeros((m,), I32),
                  y=jnp.zeros((m, dim + 1), F32), valid=jnp.zeros((m,), bool),
                  ptr=jnp.zeros((), I32), clock=jnp.zeros((m,), I32),
                  term=jnp.zeros((m,), bool))


def leaf_of(seg: Segmentation, x: jax.Array) -> jax.Array:
    """Box index (int32 (...)) of features x (..., D) in [0, 1] (upper faces at 1 included)."""
    ge = x[..., None, :] >= seg.lo
    lt = (x[..., None, :] < seg.hi) | (seg.hi >= 1.0)
    inside = jnp.all(ge & lt, axis=-1) & seg.active
    return jnp.argmax(inside, axis=-1).astype(I32)


def num_states(seg: Segmentation) -> jax.Array:
    """Number of boxes (states; the goal not counted), int32."""
    return jnp.sum(seg.active).astype(I32)


def record(buf: Buffer, x: jax.Array, a: jax.Array, y: jax.Array, valid: jax.Array,
           clock: jax.Array | int = 0, term: jax.Array | bool = False) -> Buffer:
    """Write one transition (y: change of x, scored; ``term``: it ended its episode) at
    ``ptr`` when ``valid`` (the pointer advances only then)."""
    i = buf.ptr
    w = lambda arr, v: arr.at[i].set(jnp.where(valid, v, arr[i]))  # noqa: E731
    return Buffer(x=w(buf.x, x.astype(F32)), a=w(buf.a, a.astype(I32)),
                  y=w(buf.y, y.astype(F32)), valid=w(buf.valid, valid),
                  ptr=jnp.where(valid, (i + 1) % buf.x.shape[0], i).astype(I32),
                  clock=w(buf.clock, jnp.asarray(clock, I32)),
                  term=w(buf.term, jnp.asarray(term, bool)))



def _spd_solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """Solve a w = b for symmetric positive definite a (..., Z, Z), b (..., Z, Y).

    An unrolled Cholesky (Z is small and static): elementwise ops over the batch, which
    XLA compiles far faster than a batched LAPACK solve."""
    z = a.shape[-1]
    lo = [[None] * z for _ in range(z)]
    for i in range(z):
        for j in range(i + 1):
            acc = a[..., i, j]
            for k in range(j):
                acc = acc - lo[i][k] * lo[j][k]
            if i == j:
                lo[i][i] = jnp.sqrt(jnp.maximum(acc, 1e-300))
            else:
                lo[i][j] = acc / lo[j][j]
    u = []
    for i in range(z):                                    # forward: L u = b
        acc = b[..., i, :]
        for k in range(i):
            acc = acc - lo[i][k][..., None] * u[k]
        u.append(acc / lo[i][i][..., None])
    w = [None] * z
    for i in reversed(range(z)):                          # backward: L^T w = u
        acc = u[i]
        for k in range(i + 1, z):
            acc = acc - lo[k][i][..., None] * w[k]
        w[i] = acc / lo[i][i][..., None]
    return jnp.stack(w, axis=-2)


def _sse(szz, szy, syy, n, ridge):
    """Residual sum of squares of the ridge fit from sufficient statistics (..., Z, Z),
    (..., Z, Y), (...), (...) -> (...) float64, >= 0 (0 where n = 0)."""
    z = szz.shape[-1]
    w = _spd_solve(szz + ridge * jnp.eye(z, dtype=F64), szy)
    sse = syy - 2.0 * jnp.sum(w * szy, axis=(-2, -1)) + jnp.sum(w * (szz @ w), axis=(-2, -1))
    return jnp.where(n > 0, jnp.maximum(sse, 0.0), 0.0)


def _bin_in_box(seg: Segmentation, leaf: jax.Array, x: jax.Array, bins: int) -> jax.Array:
    """Bin index (M, D) int32 of points ``x`` (M, D) along each axis of their box ``leaf``
    (M,): ``bins`` equal bins of the box's side, clipped to [0, bins)."""
    lo = seg.lo[leaf]
    width = jnp.maximum(seg.hi[leaf] - lo, 1e-12)
    return jnp.clip(jnp.floor(bins * (x - lo) / width), 0, bins - 1).astype(I32)


def _sym_index(z: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Upper-triangle rows, columns (T,) of a (z, z) matrix, T = z (z + 1) / 2, and each
    entry's position (z, z) among them."""
    r, c = np.triu_indices(z)
    pos = np.zeros((z, z), np.int32)
    pos[r, c] = pos[c, r] = np.arange(r.size)
    return r, c, pos


def _stats(seg: Segmentation, buf: Buffer, num_actions: int, bins: int, weight_out,
           boxes: jax.Array | None = None) -> list[jax.Array]:
    """Bin statistics (szz (..., Z, Z), szy (..., Z, Y), syy, n (...)) float64 of the
    buffer under the current boxes, Z = D + 1, Y = D + 1: of every box along axis 0 only,
    (L, A, 1, B, ...), or with ``boxes`` (K,) int (distinct) of those boxes along every
    axis, (K, A, D, B, ...).

    One scatter-add per axis of the T = Z (Z + 1) / 2 distinct products of ``szz`` (n is its
    last diagonal entry), ``szy`` and ``syy`` (each sum taken over the same transitions in
    buffer order as a per-statistic scatter)."""
    cap, dim = seg.lo.shape
    x = buf.x.astype(F64)
    y = buf.y.astype(F64).at[:, dim].multiply(jnp.sqrt(jnp.asarray(weight_out, F64)))
    zz = jnp.concatenate([x, jnp.ones((x.shape[0], 1), F64)], axis=1)             # (M, Z)
    r, c, pos = _sym_index(dim + 1)
    vals = jnp.concatenate([zz[:, r] * zz[:, c], (zz[:, :, None] * y[:, None, :]).reshape(
        x.shape[0], -1), jnp.sum(y * y, axis=1, keepdims=True)], axis=1)          # (M, V)
    leaf = leaf_of(seg, buf.x)
    b = _bin_in_box(seg, leaf, buf.x, bins)
    row, keep, nbox, naxes = leaf, buf.valid, cap, 1
    if boxes is not None:                       # the row of each transition's box in boxes
        hit = leaf[:, None] == boxes[None]                                        # (M, K)
        row, keep = jnp.argmax(hit, axis=1), keep & jnp.any(hit, axis=1)
        nbox, naxes = boxes.shape[0], dim
    nseg = nbox * num_actions * bins
    idx = jnp.where(keep[:, None], (row * num_actions + buf.a)[:, None] * bins + b, nseg)
    s = jnp.stack([jax.ops.segment_sum(vals, idx[:, d], nseg) for d in range(naxes)], 1)
    s = s.reshape(nbox, num_actions, bins, naxes, -1).swapaxes(2, 3)    # (K, A, D', B, V)
    t = r.size
    szz = s[..., pos]
    szy = s[..., t:-1].reshape(s.shape[:-1] + (dim + 1, dim + 1))
    return [szz, szy, s[..., -1], szz[..., dim, dim]]


def _continues(seg: Segmentation, buf: Buffer):
    """Per buffered transition: does its successor in the buffer continue the same action
    (next clock, same primitive, not terminal, ``x' = x + dx`` still in the same box)?
    Returns (cont (M,) bool, scored (M,) bool, sn (M,) int32 the box of x')."""
    m, dim = buf.x.shape
    scored = buf.y[:, dim] > 0.5
    xn = jnp.clip(buf.x + buf.y[:, :dim], 0.0, 1.0)
    s, sn = leaf_of(seg, buf.x), leaf_of(seg, xn)
    idx = jnp.arange(m, dtype=I32)
    succ = (idx + 1) % m
    newest = (buf.ptr - 1) % m
    cont = (buf.valid & buf.valid[succ] & (idx != newest) & (buf.clock[succ] == buf.clock + 1)
            & ~buf.term & ~scored & (buf.a[succ] == buf.a) & (sn == s))
    return cont, scored, sn


def _chain_end(cont: jax.Array) -> jax.Array:
    """Last transition (int32 (M,)) of each transition's chain, by pointer doubling
    (log2(M) gathers) over ``cont`` (M,) bool (the successor continues the chain)."""
    m = cont.shape[0]
    idx = jnp.arange(m, dtype=I32)
    nxt = jnp.where(cont, (idx + 1) % m, idx)
    for _ in range(max(1, int(np.ceil(np.log2(m))))):
        nxt = nxt[nxt]
    return nxt


def td_targets(seg: Segmentation, buf: Buffer, q: jax.Array, gamma: Any) -> jax.Array:
    """TD target (float32 (M,)) of every buffered transition under the current boxes and Q.

    An *action* of the learner holds its primitive while the box does not change, so a
    transition whose successor in the buffer continues it (next clock, same primitive, not
    terminal, and ``x' = x + dx`` still in the same box) takes the target of its successor;
    the last transition of such a chain gets ``1`` if it scored, ``0`` if it ended the
    episode without scoring, else ``gamma * max_a Q(box(x'), a)`` - the learner's own
    Q-learning target per action. Chains are followed by pointer doubling (log2(M)
    gathers). The newest transition ends its chain (its successor is unknown yet); invalid
    slots give 0 (they are never counted)."""
    g = jnp.asarray(gamma, F32)
    cont, scored, sn = _continues(seg, buf)
    base = jnp.where(scored, 1.0, jnp.where(buf.term, 0.0, g * jnp.max(q[sn], axis=-1)))
    return jnp.where(buf.valid, base[_chain_end(cont)], 0.0).astype(F32)


def _value_stats(seg: Segmentation, buf: Buffer, target: jax.Array, num_actions: int,
                 bins: int):
    """Sums of TD targets and counts per (box, primitive, axis, bin, half): (L, A, D, B, 2)
    float64; half = buffer slot parity (two interleaved halves of the data, for the
    cross-fitted greedy value)."""
    cap, dim = seg.lo.shape
    leaf = leaf_of(seg, buf.x)
    b = _bin_in_box(seg, leaf, buf.x, bins)
    half = (jnp.arange(buf.x.shape[0], dtype=I32) % 2)[:, None]
    base = (leaf * num_actions + buf.a) * dim
    idx = ((base[:, None] + jnp.arange(dim, dtype=I32)[None]) * bins + b) * 2 + half
    nseg = cap * num_actions * dim * bins * 2
    idx = jnp.where(buf.valid[:, None], idx, nseg).reshape(-1)
    t = target.astype(F64)
    vals = jnp.stack([jnp.broadcast_to(t[:, None], b.shape),
                      jnp.ones(b.shape, F64)], axis=-1).reshape(-1, 2)
    s = jax.ops.segment_sum(vals, idx, nseg + 1)[:-1]
    s = s.reshape((cap, num_actions, dim, bins, 2, 2))
    return s[..., 0], s[..., 1]


def _greedy_value(tsum, tcnt, min_count, crossfit):
    """Value of acting greedily from target sums / counts (L, A, ..., 2 halves): the max
    over primitives (axis 1) of the mean target, primitives with >= ``min_count``
    transitions only; with ``crossfit`` the primitive is chosen on one half of the data and
    its mean taken on the other (both ways, averaged; a primitive needs ``min_count / 2``
    in each half), which removes the upward bias of a max over noisy means. -inf where no
    primitive qualifies."""
    s, c = tsum.sum(axis=-1), tcnt.sum(axis=-1)
    plain = jnp.max(jnp.where(c >= min_count, s / jnp.maximum(c, 1.0), -jnp.inf), axis=1)
    mean = tsum / jnp.maximum(tcnt, 1.0)
    qual = jnp.all(tcnt >= 0.5 * min_count, axis=-1, keepdims=True)
    pick = jnp.argmax(jnp.where(qual, mean, -jnp.inf), axis=1, keepdims=True)   # per half
    other = jnp.take_along_axis(mean[..., ::-1], pick, axis=1)[:, 0]   # other half's mean
    cross = jnp.where(jnp.any(qual, axis=1)[..., 0], other.mean(axis=-1), -jnp.inf)
    return jnp.where(jnp.asarray(crossfit, bool), cross, plain)



class _Cut(NamedTuple):
    """The best cut of one criterion: made (() bool), box, axis and cut index (bins < c + 1
    go left), () int."""

    made: jax.Array
    leaf: jax.Array
    axis: jax.Array
    c: jax.Array


def _best_cut(score: jax.Array, dim: int, bins: int) -> tuple[jax.Array, ...]:
    """(made, box row, axis, cut) of the largest finite ``score`` (K, D, B-1), flattened;
    the box row indexes the K boxes scored."""
    best = jnp.argmax(score)
    row, rem = best // (dim * (bins - 1)), best % (dim * (bins - 1))
    return jnp.isfinite(score[best]), row, rem // (bins - 1), rem % (bins - 1)


def _cut_fits(width: jax.Array, bins: int, min_width: Any) -> jax.Array:
    """Both sides of each cut c = 1..B-1 of a box side ``width`` (..., D, 1) are at least
    ``min_width`` wide: (..., D, B-1) bool."""
    frac = jnp.arange(1, bins, dtype=F32)[None, None] / bins                      # cut position
    return (frac * width >= min_width) & ((1 - frac) * width >= min_width)


def _merge_partners(seg: Segmentation, n_box: jax.Array, min_samples: Any
                    ) -> tuple[jax.Array, jax.Array]:
    """Each box's merge partner (L,) int and whether it has one (L,) bool: the adjacent
    active box (union a box) holding the most transitions, both holding ``min_samples``."""
    dim = seg.lo.shape[1]
    lo_i, lo_j = seg.lo[:, None], seg.lo[None]
    hi_i, hi_j = seg.hi[:, None], seg.hi[None]
    same = (lo_i == lo_j) & (hi_i == hi_j)                                        # (L, L, D)
    touch = (hi_i == lo_j) | (hi_j == lo_i)
    n_same = jnp.sum(same, axis=-1)
    adj = (n_same == dim - 1) & jnp.any(touch & ~same, axis=-1)
    adj = (adj & seg.active[:, None] & seg.active[None] & (n_box[:, None] >= min_samples)
           & (n_box[None] >= min_samples))
    return jnp.argmax(jnp.where(adj, n_box[None], -1.0), axis=1), jnp.any(adj, axis=1)


def _model_criterion(seg: Segmentation, buf: Buffer, tots: list[jax.Array],
                     partner: jax.Array, p: SegmentationParams
                     ) -> tuple[_Cut, jax.Array, jax.Array, jax.Array]:
    """The model-error split and the residuals a merge needs.

    ``tots``: each box's sums (L, A, ...) of :func:`_stats`. Cuts are evaluated for the
    ``split_candidates`` boxes with the largest residual per transition only (their bin
    sums along every axis taken here), with one batched residual computation for the cut
    sides and each box's union with ``partner``. Returns (the best cut, each box's
    transitions (L,), residual (L,) and residual of its union with its partner (L,))."""
    cap, dim = seg.lo.shape
    nb, ridge = p.bins, jnp.asarray(p.ridge, F64)
    n_box = tots[3].sum(axis=1)                                                   # (L,)
    sse_box = _sse(*tots, ridge).sum(axis=1)                                      # (L,)
    err = sse_box / jnp.maximum(n_box, 1.0)
    elig = seg.active & (err > p.split_error)
    _, cand = jax.lax.top_k(jnp.where(elig, err, -jnp.inf), min(p.split_candidates, cap))
    # candidate cuts of the candidates: left = bins < c, c = 1..B-1
    stats = _stats(seg, buf, tots[3].shape[1], nb, p.outcome_weight, cand)
    cum = [jnp.cumsum(a, axis=3)[:, :, :, :-1] for a in stats]                   # (K, A, D, B-1)
    right = [jnp.expand_dims(t[cand], (2, 3)) - c for t, c in zip(tots, cum, strict=True)]
    u = [t + t[partner] for t in tots]                                            # (L, A, ...)
    groups = (cum, right, u)
    lead = [g[3].shape for g in groups]
    flat = [jnp.concatenate([g[i].reshape((-1,) + g[i].shape[len(lead[k]):])
                             for k, g in enumerate(groups)]) for i in range(4)]
    sse_all = _sse(*flat, ridge)
    sizes = [int(np.prod(sh)) for sh in lead]
    parts = jnp.split(sse_all, np.cumsum(sizes)[:-1])
    sse_l, sse_r, sse_u = (pt.reshape(sh) for pt, sh in zip(parts, lead, strict=True))
    sse_l, sse_r = sse_l.sum(axis=1), sse_r.sum(axis=1)                           # (K, D, B-1)
    n_l, n_r = cum[3].sum(axis=1), right[3].sum(axis=1)
    gain = ((sse_box[cand][:, None, None] - sse_l - sse_r)
            / jnp.maximum(n_box[cand], 1.0)[:, None, None])
    ok = (elig[cand][:, None, None]
          & (gain >= p.split_gain) & (n_l >= p.min_samples) & (n_r >= p.min_samples)
          & _cut_fits((seg.hi - seg.lo)[cand][:, :, None], nb, p.min_width)
          & ~jnp.all(seg.active))
    made, row, axis, c = _best_cut(jnp.where(ok, gain, -jnp.inf).reshape(-1), dim, nb)
    return _Cut(made, cand[row], axis, c), n_box, sse_box, sse_u.sum(axis=1)


def _value_criterion(seg: Segmentation, buf: Buffer, q: jax.Array, p: SegmentationParams
                     ) -> tuple[_Cut, tuple[jax.Array, ...]]:
    """The value-driven split (``value_split_gain > 0``): TD targets of the buffered
    transitions summed per (box, primitive, axis, bin); a cut's gain is the greedy value
    per transition of its two sides acted on separately minus that of the whole box.
    Returns (the best cut, each box's (target sums (L, A, 2), counts (L, A, 2), greedy
    value (L,), transitions (L,)) for the merge veto)."""
    dim, nb = seg.lo.shape[1], p.bins
    tgt = td_targets(seg, buf, q, p.discount)
    tsum, tcnt = _value_stats(seg, buf, tgt, q.shape[1], nb)                  # (L, A, D, B)
    b_sum, b_cnt = tsum[:, :, 0].sum(axis=2), tcnt[:, :, 0].sum(axis=2)           # (L, A, 2)
    mc, xf = p.value_min_count, p.value_crossfit
    v_box = _greedy_value(b_sum, b_cnt, mc, xf)                                   # (L,)
    l_sum, l_cnt = (jnp.cumsum(a, axis=3)[:, :, :, :-1] for a in (tsum, tcnt))    # (L,A,D,B-1,2)
    r_sum = b_sum[:, :, None, None] - l_sum
    r_cnt = b_cnt[:, :, None, None] - l_cnt
    v_l = _greedy_value(l_sum, l_cnt, mc, xf)                                     # (L, D, B-1)
    v_r = _greedy_value(r_sum, r_cnt, mc, xf)
    vn_l, vn_r = l_cnt.sum(axis=(1, -1)), r_cnt.sum(axis=(1, -1))
    vn_box = b_cnt.sum(axis=(1, -1))
    v_gain = ((vn_l * v_l + vn_r * v_r) / jnp.maximum(vn_box, 1.0)[:, None, None]
              - v_box[:, None, None])
    v_ok = ((jnp.asarray(p.value_split_gain) > 0) & seg.active[:, None, None]
            & jnp.isfinite(v_gain) & (v_gain >= p.value_split_gain)
            & (vn_l >= p.min_samples) & (vn_r >= p.min_samples)
            & _cut_fits((seg.hi - seg.lo)[:, :, None], nb, p.min_width)
            & ~jnp.all(seg.active))
    cut = _Cut(*_best_cut(jnp.where(v_ok, v_gain, -jnp.inf).reshape(-1), dim, nb))
    return cut, (b_sum, b_cnt, v_box, vn_box)


def _split(seg: Segmentation, q: jax.Array, cut: _Cut, p: SegmentationParams
           ) -> tuple[Segmentation, jax.Array]:
    """``seg`` with box ``cut.leaf`` cut in two (the upper side in the first free slot),
    and Q with the new box's row (its parent's, or ``q_init``)."""
    leaf, axis, c = cut.leaf, cut.axis, cut.c
    lo, hi = seg.lo[leaf, axis], seg.hi[leaf, axis]
    at = lo + (c + 1).astype(F32) / p.bins * (hi - lo)
    new = jnp.argmin(seg.active)                                                  # free slot
    s_lo = seg.lo.at[new].set(seg.lo[leaf].at[axis].set(at))
    s_hi = seg.hi.at[new].set(seg.hi[leaf]).at[leaf, axis].set(at)
    q_new = jnp.where(p.inherit_q, q[leaf], jnp.full((q.shape[1],), p.q_init, F32))
    return (Segmentation(lo=s_lo, hi=s_hi, active=seg.active.at[new].set(True)),
            q.at[new].set(q_new))


def _merge(seg: Segmentation, q: jax.Array, partner: jax.Array, has_partner: jax.Array,
           residuals: tuple[jax.Array, ...], values: tuple[jax.Array, ...],
           p: SegmentationParams) -> tuple[jax.Array, Segmentation, jax.Array]:
    """(made, boxes, Q) of the merge of the box whose union with its partner raises the
    residual least (``residuals``: transitions, residual and union residual per box);
    with the value criterion on, not a pair whose greedy value gains from staying apart
    (``values``: :func:`_value_criterion`'s). The merged box's Q is the pair's mean."""
    n_box, sse_box, sse_u = residuals
    b_sum, b_cnt, v_box, vn_box = values
    n_u = n_box + n_box[partner]
    rise = (sse_u - sse_box - sse_box[partner]) / jnp.maximum(n_u, 1.0)
    u_sum, u_cnt = b_sum + b_sum[partner], b_cnt + b_cnt[partner]
    vn_u = vn_box + vn_box[partner]
    apart = ((vn_box * v_box + vn_box[partner] * v_box[partner]) / jnp.maximum(vn_u, 1.0)
             - _greedy_value(u_sum, u_cnt, p.value_min_count, p.value_crossfit))
    veto = (jnp.asarray(p.value_split_gain) > 0) & jnp.isfinite(apart) & (
        apart > p.value_merge_tol)
    m_score = jnp.where(has_partner & (rise <= p.merge_tol) & ~veto, -rise, -jnp.inf)
    i = jnp.argmax(m_score)
    j = partner[i]
    merged = Segmentation(lo=seg.lo.at[i].set(jnp.minimum(seg.lo[i], seg.lo[j])),
                          hi=seg.hi.at[i].set(jnp.maximum(seg.hi[i], seg.hi[j])),
                          active=seg.active.at[j].set(False))
    return jnp.isfinite(m_score[i]), merged, q.at[i].set(0.5 * (q[i] + q[j]))


def structure_update(seg: Segmentation, buf: Buffer, q: jax.Array, p: SegmentationParams
                     ) -> tuple[Segmentation, jax.Array, jax.Array, jax.Array, jax.Array]:
    """Refit the local models from the buffer; split one box (the value criterion first,
    else the model error), or else merge two.

    Cost control (fixed shapes): cuts are evaluated for the ``split_candidates`` boxes with
    the largest residual per transition only, and each box is tried for a merge with one
    partner (the adjacent box, union a box, holding the most transitions).

    Args: the boxes, the buffer, q (L, A) float32 the Q table (TD targets of the value
    criterion; a new box's values, a merged box's mean), p (static shapes and thresholds).
    Returns (boxes, q (L, A), split () bool, merge () bool, value split () bool: the split
    was made by the value criterion).
    """
    _require_x64()
    tots = [a[:, :, 0].sum(axis=2)                    # each box's sums (L, A, ...): bins of
            for a in _stats(seg, buf, q.shape[1], p.bins, p.outcome_weight)]  # axis 0 summed
    n_box = tots[3].sum(axis=1)                                                   # (L,)
    partner, has_partner = _merge_partners(seg, n_box, p.min_samples)
    m_cut, *residuals = _model_criterion(seg, buf, tots, partner, p)
    v_cut, values = _value_criterion(seg, buf, q, p)
    cut = _Cut(v_cut.made | m_cut.made,
               *(jnp.where(v_cut.made, v, m).astype(I32)
                 for v, m in zip(v_cut[1:], m_cut[1:], strict=True)))
    split_seg, split_q = _split(seg, q, cut, p)
    merged, merge_seg, merge_q = _merge(seg, q, partner, has_partner, residuals, values, p)
    do_merge = merged & ~cut.made
    pick = lambda a, b, c0: jnp.where(cut.made, a, jnp.where(do_merge, b, c0))  # noqa: E731
    seg2 = jax.tree_util.tree_map(pick, split_seg, merge_seg, seg)
    return seg2, pick(split_q, merge_q, q), cut.made, do_merge, v_cut.made
