"""Figure 5's map from a run's ``final`` arrays, and its figures.

:func:`map_of` rebuilds one learner's :class:`~vbl.spaces.action_cells.CellMap` from the
arrays :func:`vbl.programs.action_map_program.make_action_map_program` returns;
:func:`plot_fig5` draws it on Figure 5's slice (ball size x1 along the columns, goal size
x3 along the rows, ball and goal centred, goal frontal, both objects seen) with the grid
baseline's boundaries over it, :func:`plot_refined` draws the refined policy on the same
slice. ``final`` holds arrays (seeds, ...) of one sweep point.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from vbl.engine.plots import save_figure
from vbl.spaces.action_based import FeatureParams
from vbl.spaces.action_cells import CellMap, CellMapParams, cell_index, classify_cells
from vbl.spaces.cell_refine import initial_units
from vbl.spaces.grid import GridParams
from vbl.world.robots import action_labels

__all__ = ["map_arrays", "map_of", "slice_features", "plot_fig5", "plot_refined"]

ROBOT = "two_motor"  #: robot whose primitive labels the figures show


def map_arrays(cm: CellMap) -> dict:
    """The arrays of ``cm`` that :func:`map_of` reads, float32 (jit-able; the static fields
    and ``iterations`` are not included)."""
    f = lambda a: jnp.asarray(a).astype(jnp.float32)  # noqa: E731
    return {k: f(getattr(cm, k)) for k in ("action", "transitions", "order", "active", "edges",
                                           "cell_state", "cell_time", "cell_transitions",
                                           "fallback")}


def map_of(final: dict, seed: int, cells: CellMapParams) -> CellMap:
    """The cell map of learner ``seed`` from a run's ``final`` arrays (``cells``: the run's
    cell settings, for the static fields)."""
    g = lambda k, t=np.float32: np.asarray(final[k])[seed].astype(t)  # noqa: E731
    return CellMap(edges=g("edges"), cell_state=g("cell_state", np.int32),
                   cell_time=g("cell_time"), cell_transitions=g("cell_transitions", np.int32),
                   fallback=g("fallback", np.int32), action=g("action", np.int32),
                   transitions=g("transitions", np.int32), order=g("order", np.int32),
                   active=g("active", bool), iterations=np.int32(0), bins=tuple(cells.bins),
                   categorical_dims=cells.categorical_dims,
                   categorical_levels=cells.categorical_levels)


def slice_features(dim: int, n: int) -> np.ndarray:
    """Feature vectors (n, n, dim) float32 of Figure 5's slice: x1 (ball size) along the
    columns, x3 (goal size) along the rows, both at bin centres of [0, 1]; every other
    feature 0.5 (x2 = x4 = 0 px, x5 = 0, both objects seen)."""
    u = (np.arange(n) + 0.5) / n
    b, g = np.meshgrid(u, u)
    x = np.full((n, n, dim), 0.5, np.float32)
    x[..., 0], x[..., 2] = b, g
    return x


def _draw_slice(fp: FeatureParams, gp: GridParams, region: np.ndarray, shade: np.ndarray,
                label: Callable[[int], str], title: str, path: Path) -> Path:
    """Draw regions (n, n) int (< 0: none) of the slice, grey ``shade`` (n, n) in [0, 1],
    ``label(region)`` at each region's centre, the grid's boundaries in blue."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = region.shape[0]
    fig, ax = plt.subplots(figsize=(5.5, 5))
    ax.imshow(shade, origin="lower", extent=(0, fp.ball_size_max, 0, fp.goal_size_max),
              cmap="gray", vmin=0, vmax=1, aspect="auto")
    for r in np.unique(region[region >= 0]):
        rr, cc = np.nonzero(region == r)
        ax.text((cc.mean() + 0.5) / n * fp.ball_size_max, (rr.mean() + 0.5) / n
                * fp.goal_size_max, label(r), ha="center", va="center", fontsize=8,
                color="red")
    for v in (gp.ball_size_lower, gp.ball_size_upper):
        ax.axvline(v, color="C0", lw=1)
    for v in (gp.goal_size_lower, gp.goal_size_upper):
        ax.axhline(v, color="C0", lw=1)
    ax.set_xlabel("ball size x1 [px]")
    ax.set_ylabel("goal size x3 [px]")
    ax.set_title(title, fontsize=10)
    return save_figure(fig, path)


def plot_fig5(final: dict, cells: CellMapParams, fp: FeatureParams, gp: GridParams,
              out: Path, seed: int = 0, n: int = 160) -> Path:
    """``out/fig5_state_map.png``: the map of learner ``seed`` on Figure 5's slice (``n`` x
    ``n`` points); darker = earlier division, label = primitive + transitions to the
    goal; ``gp``: the grid whose boundaries are drawn."""
    sm = map_of(final, seed, cells)
    s = np.asarray(classify_cells(sm, jnp.asarray(slice_features(fp.dim, n))))
    order = np.where(s >= 0, np.asarray(sm.order)[np.maximum(s, 0)], -1)
    n_it = max(int(np.asarray(sm.order)[np.asarray(sm.active)].max(initial=0)) + 1, 1)
    shade = np.where(order >= 0, 0.15 + 0.7 * order / n_it, 1.0)
    labels = action_labels(ROBOT)
    return _draw_slice(
        fp, gp, s, shade,
        lambda st: f"{labels[int(sm.action[st])]}$_{{{int(sm.transitions[st])}}}$",
        f"Fig. 5 map (cells, seed {seed}): {int(np.asarray(sm.active).sum())} "
        "states; blue = grid", Path(out) / "fig5_state_map.png")


def plot_refined(final: dict, cells: CellMapParams, units: str, fp: FeatureParams,
                 gp: GridParams, out: Path, seed: int = 0, n: int = 160) -> Path:
    """``out/fig5_refined_map.png``: the refined policy of learner ``seed`` (``units``: the
    run's ``refine.units``) on Figure 5's slice; label = primitive + transitions to the
    goal, darker = fewer transitions, white = never reached the goal in the refinement."""
    cm = map_of(final, seed, cells)
    unit_of, _ = initial_units(cm, units)
    pol = np.asarray(final["refined_policy"])[seed].astype(int)
    trans = np.asarray(final["refined_transitions"])[seed].astype(int)
    idx = np.asarray(cell_index(cm, jnp.asarray(slice_features(fp.dim, n))))
    unit = np.asarray(unit_of)[idx]
    t = trans[unit]
    shade = np.where(t > 0, 0.15 + 0.7 * (t - 1) / max(int(trans.max(initial=1)), 1), 1.0)
    labels = action_labels(ROBOT)
    return _draw_slice(
        fp, gp, np.where(t > 0, unit, -1), shade,
        lambda un: f"{labels[pol[un]]}$_{{{trans[un]}}}$",
        f"refined map (seed {seed}): {int(np.asarray(final['refined_states'])[seed])} "
        "states; blue = grid", Path(out) / "fig5_refined_map.png")
