"""Figure 5's map serialisation and figures (vbl.programs.map_figures), and the run folders
and presets of fig5_action_based: a map survives its trip through a run's ``final``
arrays (it classifies every point as the original does), the slice holds the features
Figure 5 names, and the committed run folders rebuild to the README's preset commands."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from toy_worlds import line_world_collector

from vbl.programs.map_figures import map_arrays, map_of, slice_features
from vbl.spaces.action_cells import (
    CellMapParams,
    build_cell_map,
    cell_index,
    cell_policy_action,
    classify_cells,
)

ROOT = Path(__file__).resolve().parents[1]
LINE = CellMapParams(bins=(20,), seen_feature=(-1,), spacing="uniform", categorical_dims=0,
                     start_window=20, max_iterations=4, min_points=5.0, min_reliability=0.8)


def test_map_survives_the_final_arrays_of_a_run():
    """Two learners' maps (different keys) stacked as the engine stacks seeds: each
    rebuilt map assigns every point the original's cell, state and primitive."""
    collect = line_world_collector(200, 40)
    maps = [build_cell_map(collect(jax.random.PRNGKey(s), 0.5), LINE) for s in (0, 1)]
    arrays = [map_arrays(m) for m in maps]
    assert all(v.dtype == jnp.float32 for v in arrays[0].values())
    final = {k: np.stack([np.asarray(a[k]) for a in arrays]) for k in arrays[0]}
    x = jnp.linspace(0.0, 1.0, 401, dtype=jnp.float32)[:, None]
    for seed, cm in enumerate(maps):
        back = map_of(final, seed, LINE)
        assert int(np.asarray(cm.active).sum()) > 0
        for fn in (cell_index, classify_cells, cell_policy_action):
            np.testing.assert_array_equal(np.asarray(fn(back, x)), np.asarray(fn(cm, x)))


def test_slice_is_ball_size_by_goal_size_with_centred_objects():
    x = slice_features(7, 4)
    centres = [0.125, 0.375, 0.625, 0.875]
    assert x.shape == (4, 4, 7) and x.dtype == np.float32
    np.testing.assert_array_equal(x[2, :, 0], centres)     # ball size along the columns
    np.testing.assert_array_equal(x[:, 1, 2], centres)     # goal size along the rows
    np.testing.assert_array_equal(x[..., [1, 3, 4, 5, 6]], 0.5)
