"""Off-line, action-based construction on quantile cells (paper Section 2.1).

A state is a set of input vectors from which repeating one kind of primitive reaches the
goal or a state built before; states grow backwards from the goal over the experience of
:mod:`vbl.spaces.action_based`. The clusters are cells instead of the paper's
hyper-ellipsoids: each continuous feature is cut into ``bins[d]`` bins (quantiles or
equal widths), each categorical pattern has its own cells, and a state is the union of the
cells labelled with the same primitive at the same iteration. An iteration labels every
unlabelled cell with its qualifying primitive of highest ``reliability * discount**time``;
the construction stops when an iteration labels nothing. Fixed-shape, jit- and vmap-able.

See docs/state_spaces.md, "Cells" (the labelling rule, the policy in unlabelled cells).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from vbl.params import ParamError, param, validate
from vbl.spaces.action_based import Experience, pattern_of

__all__ = [
    "CellMapParams",
    "CellMap",
    "build_cell_map",
    "check_cells",
    "make_cell_builder",
    "cell_index",
    "classify_cells",
    "cell_policy_action",
    "num_cell_states",
]

F32 = jnp.float32
I32 = jnp.int32
NO_EDGE = float(np.finfo(np.float32).max)
"""Padding of unused bin edges (above every feature value; finite, so that a map survives a
round trip through ``summary.json``)."""


@struct.dataclass
class CellMapParams:
    """Cells and thresholds of the cell construction (defaults: Figure 5's, measured in
    docs/findings/fig5_action_based.md)."""

    bins: tuple[int, ...] = param((4, 5, 3, 3, 1), doc="quantile bins per continuous feature "
                                  "(Section 2: x1 ball size, x2 ball position, x3 goal size, x4 "
                                  "goal position, x5 goal orientation; 1 = feature not used)",
                                  static=True, ge=1)
    seen_feature: tuple[int, ...] = param((5, 5, 6, 6, 6), doc="per continuous feature: index "
                                          "of the feature whose value 0.5 marks its object as "
                                          "seen (bin edges are quantiles over those points; "
                                          "Section 2: the lost-side features); -1 = all points",
                                          static=True, ge=-1)
    spacing: str = param("quantile", doc="bin edges: 'quantile' (equal counts of the points "
                         "that see the object) or 'uniform' (equal widths between their least "
                         "and largest value)", static=True, choices=("quantile", "uniform"))
    categorical_dims: int = param(2, doc="the last this many features are categorical (cells "
                                  "of each pattern are separate; Section 2: the lost sides)",
                                  static=True, ge=0)
    categorical_levels: int = param(3, doc="values of each categorical feature, equally spaced "
                                    "in [0, 1]", static=True, ge=2)
    start_window: int = param(50, doc="first points of each episode used as start points",
                              unit="steps", static=True, ge=1)
    max_iterations: int = param(12, doc="most construction iterations", static=True, ge=1)
    min_points: float = param(5.0, doc="fewest start points of a primitive in a cell for it "
                              "to qualify", ge=1.0)
    min_reliability: float = param(0.5, doc="least fraction of a primitive's start points in "
                                   "a cell that reach the goal or a labelled cell", ge=0.0,
                                   le=1.0)
    discount: float = param(0.98, doc="per-primitive discount of the value r * discount^t "
                            "that chooses among qualifying primitives", gt=0.0, le=1.0)

    def check(self) -> None:
        if len(self.bins) != len(self.seen_feature):
            raise ParamError(f"cells.bins {self.bins} and cells.seen_feature "
                             f"{self.seen_feature} must have one entry per continuous feature")

    @property
    def num_patterns(self) -> int:
        return self.categorical_levels ** self.categorical_dims

    @property
    def num_cells(self) -> int:
        return int(np.prod(self.bins)) * self.num_patterns


@struct.dataclass
class CellMap:
    """A built cell map. edges (Dc, max(bins) - 1) float32 inner bin edges per continuous
    feature (NO_EDGE padded); cell_state (C,) int32 (-1 = remainder); cell_time (C,) float32
    expected primitives to the goal; cell_transitions (C,) int32; fallback (P,) int32 the
    remainder's primitive per categorical pattern; per state (S = max_iterations x A):
    action, transitions (fewest of its cells), order (iteration), active; iterations ()
    int32. C = prod(bins) x P cells, index = (bin index in row-major order) x P + pattern."""

    edges: jax.Array
    cell_state: jax.Array
    cell_time: jax.Array
    cell_transitions: jax.Array
    fallback: jax.Array
    action: jax.Array
    transitions: jax.Array
    order: jax.Array
    active: jax.Array
    iterations: jax.Array
    bins: tuple[int, ...] = struct.field(pytree_node=False, default=())
    categorical_dims: int = struct.field(pytree_node=False, default=0)
    categorical_levels: int = struct.field(pytree_node=False, default=3)


def _edges(x: jax.Array, valid: jax.Array, p: CellMapParams) -> jax.Array:
    """Inner bin edges (Dc, max(bins) - 1), NO_EDGE padded, from the valid points."""
    width = max(max(p.bins) - 1, 1)
    rows = []
    for d, (b, s) in enumerate(zip(p.bins, p.seen_feature, strict=True)):
        if b == 1:
            rows.append(jnp.full((width,), NO_EDGE, F32))
            continue
        mask = valid if s < 0 else valid & (jnp.abs(x[..., s] - 0.5) < 0.25)
        v = jnp.where(mask, x[..., d], jnp.nan).reshape(-1)
        frac = jnp.linspace(0.0, 1.0, b + 1)[1:-1]
        if p.spacing == "quantile":
            q = jnp.nanquantile(v, frac).astype(F32)
        else:
            lo, hi = jnp.nanmin(v), jnp.nanmax(v)
            q = (lo + frac * (hi - lo)).astype(F32)
        q = jnp.where(jnp.isfinite(q), q, NO_EDGE)    # no point sees the object: one bin
        rows.append(jnp.concatenate([q, jnp.full((width - (b - 1),), NO_EDGE, F32)]))
    return jnp.stack(rows)


def _index(edges: jax.Array, bins: tuple[int, ...], cat_dims: int, levels: int,
           x: jax.Array) -> jax.Array:
    idx = jnp.zeros(x.shape[:-1], I32)
    for d, b in enumerate(bins):
        k = jnp.sum(x[..., d, None] > edges[d], axis=-1).astype(I32)  # edges sorted
        idx = idx * b + jnp.minimum(k, b - 1)
    p = levels ** cat_dims
    return idx * p + pattern_of(x, cat_dims, levels)


def cell_index(cm: CellMap, x: jax.Array) -> jax.Array:
    """Cell (int32 (...)) of features x (..., D)."""
    return _index(cm.edges, cm.bins, cm.categorical_dims, cm.categorical_levels, x)


def check_cells(p: CellMapParams, num_features: int, horizon: int) -> None:
    """Raise ParamError unless ``p`` fits experience of ``num_features`` features and
    episodes of ``horizon`` primitives (callable before any data exists)."""
    validate(p)
    d = num_features
    if p.categorical_dims >= d:
        raise ParamError(f"cells.categorical_dims={p.categorical_dims} must be < the number of "
                         f"features {d} (some must be continuous)")
    if len(p.bins) != d - p.categorical_dims:
        raise ParamError(f"cells.bins has {len(p.bins)} entries; the experience has "
                         f"{d - p.categorical_dims} continuous features ({d} features, "
                         f"{p.categorical_dims} categorical)")
    if any(s >= d for s in p.seen_feature):
        raise ParamError(f"cells.seen_feature {p.seen_feature}: indices must be < {d}")
    if p.start_window > horizon:
        raise ParamError(f"cells.start_window={p.start_window} must be <= the collection "
                         f"horizon {horizon}")


def _check(exp: Experience, p: CellMapParams) -> None:
    if exp.x.ndim != 4:
        raise ValueError(f"experience.x must be (A, N, T+1, D), got shape {exp.x.shape}")
    check_cells(p, exp.x.shape[-1], exp.x.shape[2] - 1)


def _first_target(exp: Experience, cell: jax.Array, lab: jax.Array, ctime: jax.Array,
                  ctrans: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Per point (A, N, T) of ``exp``, given the cells' labels so far (C,) (``cell``: each
    point's cell, (A, N, T+1)): reached (bool), primitives to the goal through the first
    labelled cell or goal ahead (steps + that cell's time) and transitions (1 + the
    cell's; goal 1)."""
    lab_pt, t_pt, tr_pt = lab[cell], ctime[cell], ctrans[cell]
    hit_pt = (lab_pt >= 0) & exp.valid

    def back(nxt, inp):
        g, hit, t_next, tr_next = inp
        n_reach, n_tm, n_tr = nxt
        reach = g | hit | n_reach
        tm = 1.0 + jnp.where(g, 0.0, jnp.where(hit, t_next, n_tm))
        tr = jnp.where(g, 1, jnp.where(hit, 1 + tr_next, n_tr))
        out = (reach, tm, tr)
        return out, out

    mv = lambda a: jnp.moveaxis(a, 2, 0)  # noqa: E731
    xs = (mv(exp.goal), mv(hit_pt[..., 1:]), mv(t_pt[..., 1:]), mv(tr_pt[..., 1:]))
    shp = exp.goal.shape[:2]
    init = (jnp.zeros(shp, bool), jnp.zeros(shp, F32), jnp.zeros(shp, I32))
    _, outs = jax.lax.scan(back, init, xs, reverse=True)
    return tuple(jnp.moveaxis(o, 0, 2) for o in outs)


def _label_iteration(carry: tuple, exp: Experience, cell: jax.Array, p: CellMapParams
                     ) -> tuple:
    """One growth iteration: label every unlabelled cell with its qualifying primitive of
    highest ``reliability * discount**time`` over the start window's points. ``carry``:
    (iteration, labels (C,) int32, times (C,) float32, transitions (C,) int32, any new)."""
    it, lab, ctime, ctrans, _ = carry
    n_act, n_cells, w = exp.x.shape[0], p.num_cells, p.start_window
    flat = lambda a: a[:, :, :w].reshape(n_act, -1)  # noqa: E731
    starts_cell, starts_valid = flat(cell), flat(exp.valid)
    per_cell = jax.vmap(lambda ids, weights: jax.ops.segment_sum(weights, ids,
                                                                 num_segments=n_cells))
    reach, tm, tr = _first_target(exp, cell, lab, ctime, ctrans)
    start = starts_valid & (lab[starts_cell] < 0)
    ok_pt = start & flat(reach)
    n_in = per_cell(starts_cell, start.astype(F32))                              # (A, C)
    n_ok = per_cell(starts_cell, ok_pt.astype(F32))
    s_tm = per_cell(starts_cell, jnp.where(ok_pt, flat(tm), 0.0))
    s_tr = per_cell(starts_cell, jnp.where(ok_pt, flat(tr), 0).astype(F32))
    rel = n_ok / jnp.maximum(n_in, 1.0)
    e_tm = s_tm / jnp.maximum(n_ok, 1.0)
    ok = (n_in >= p.min_points) & (rel >= p.min_reliability) & (lab < 0)[None]
    value = jnp.where(ok, rel * jnp.asarray(p.discount, F32) ** e_tm, -1.0)
    best = jnp.argmax(value, axis=0).astype(I32)                                 # (C,)
    new = jnp.any(ok, axis=0)
    pick = lambda a: jnp.take_along_axis(a, best[None], axis=0)[0]  # noqa: E731
    lab = jnp.where(new, it * n_act + best, lab)
    ctime = jnp.where(new, pick(e_tm), ctime)
    ctrans = jnp.where(new, jnp.round(pick(s_tr) / jnp.maximum(pick(n_ok), 1.0)).astype(I32),
                       ctrans)
    return it + 1, lab, ctime, ctrans, jnp.any(new)


def _assemble(edges: jax.Array, lab: jax.Array, ctime: jax.Array, ctrans: jax.Array,
              iterations: jax.Array, n_act: int, p: CellMapParams) -> CellMap:
    """The :class:`CellMap` of the cells' final labels, times and transitions: the states'
    primitives, order and transitions (the fewest of their cells), and each pattern's
    fallback primitive (the most frequent among its labelled cells)."""
    s_cap, n_cells, n_pat = p.max_iterations * n_act, p.num_cells, p.num_patterns
    labelled = lab >= 0
    seg = jnp.where(labelled, lab, s_cap)                                 # dump bucket s_cap
    active = jax.ops.segment_sum(labelled.astype(I32), seg, num_segments=s_cap + 1)[:s_cap] > 0
    big = jnp.iinfo(I32).max
    trans = jax.ops.segment_min(jnp.where(labelled, ctrans, big), seg,
                                num_segments=s_cap + 1)[:s_cap]
    act = jnp.where(labelled, lab % n_act, 0)
    counts = jax.ops.segment_sum(jax.nn.one_hot(act, n_act, dtype=F32) * labelled[:, None],
                                 jnp.arange(n_cells) % n_pat, num_segments=n_pat)  # (P, A)
    return CellMap(edges=edges, cell_state=lab, cell_time=ctime,
                   cell_transitions=jnp.where(labelled, ctrans, 0), fallback=jnp.argmax(
                       counts, axis=-1).astype(I32),
                   action=jnp.tile(jnp.arange(n_act, dtype=I32), p.max_iterations),
                   transitions=jnp.where(active, trans, 0),
                   order=jnp.repeat(jnp.arange(p.max_iterations, dtype=I32), n_act),
                   active=active, iterations=iterations, bins=tuple(p.bins),
                   categorical_dims=p.categorical_dims,
                   categorical_levels=p.categorical_levels)


def build_cell_map(exp: Experience, p: CellMapParams) -> CellMap:
    """Grow the cell states backwards from the goal (module docstring): label cells one
    iteration at a time until an iteration labels nothing or ``p.max_iterations`` is
    reached. Jit-able with ``p`` closed over (traced thresholds may be vmapped);
    :func:`make_cell_builder` checks and jits. Deterministic: no key."""
    edges = _edges(exp.x, exp.valid, p)
    cell = _index(edges, p.bins, p.categorical_dims, p.categorical_levels, exp.x)  # (A,N,T1)
    n_cells = p.num_cells
    init = (jnp.zeros((), I32), jnp.full((n_cells,), -1, I32), jnp.zeros((n_cells,), F32),
            jnp.zeros((n_cells,), I32), jnp.ones((), bool))
    it, lab, ctime, ctrans, _ = jax.lax.while_loop(
        lambda carry: (carry[0] < p.max_iterations) & carry[4],
        lambda carry: _label_iteration(carry, exp, cell, p), init)
    return _assemble(edges, lab, ctime, ctrans, it, exp.x.shape[0], p)


def make_cell_builder(p: CellMapParams) -> Callable[[Experience], CellMap]:
    """Validated, jitted ``build(exp) -> CellMap`` for the settings ``p``."""
    validate(p)
    _build = jax.jit(lambda exp: build_cell_map(exp, p))

    def build(exp: Experience) -> CellMap:
        _check(exp, p)
        return _build(exp)

    return build


def classify_cells(cm: CellMap, x: jax.Array) -> jax.Array:
    """State (int32 (...)) of features x (..., D); -1 in the remainder."""
    return cm.cell_state[cell_index(cm, x)]


def cell_policy_action(cm: CellMap, x: jax.Array) -> jax.Array:
    """The map's primitive for features x (..., D): the labelled cell's, else the
    remainder's primitive of x's categorical pattern (int32 (...))."""
    c = cell_index(cm, x)
    s = cm.cell_state[c]
    fb = cm.fallback[c % (cm.categorical_levels ** cm.categorical_dims)]
    return jnp.where(s >= 0, cm.action[jnp.maximum(s, 0)], fb).astype(I32)


def num_cell_states(cm: CellMap) -> jax.Array:
    """Number of built states (the goal not counted), int32."""
    return jnp.sum(cm.active).astype(I32)
