"""The hand-designed grid: hand-built Section-2 feature vectors map to the expected states,
including lost and partially observed objects; boundaries are parameters."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vbl  # noqa: F401
from vbl.params import ParamError, validate
from vbl.spaces.grid import NUM_GRID_STATES, GridParams, grid_state, state_label


def obs(ball=None, goal=None, ball_lost=0, goal_lost=0):
    """Section-2 vector: ball=(diameter x1, position x2), goal=(size x3, pos x4, orient x5);
    None = lost, to the side ball_lost / goal_lost (-1 left, +1 right)."""
    v = np.zeros(9, np.float32)
    if ball is not None:
        v[0], v[1], v[5] = ball[0], ball[1], 1.0
    else:
        v[7] = ball_lost
    if goal is not None:
        v[2], v[3], v[4], v[6] = goal[0], goal[1], goal[2], 1.0
    else:
        v[8] = goal_lost
    return v


# (observation, expected state) with the default boundaries (+-85.3 px; ball 40/100 px;
# goal 50/100 px; orientation +-0.1). State = 29 * ball + goal, ball = 3 * pos + size,
# goal = 9 * pos + 3 * size + orient; lost ball 9 (left) / 10 (right), goal 27 / 28.
CASES = [
    (obs((60, 0), (150, 0, 0.0)), 29 * 4 + 16),             # centred, medium ball, large goal
    (obs((20, -200), (30, 200, -0.5)), 29 * 0 + 18 + 0),     # small left ball; small right goal
    (obs((120, 100), (70, -100, 0.3)), 29 * 8 + 0 + 3 + 2),  # large right ball; medium left
    (obs(None, (70, 0, 0.0), ball_lost=-1), 29 * 9 + 9 + 3 + 1),
    (obs(None, (70, 0, 0.0), ball_lost=+1), 29 * 10 + 13),
    (obs((60, 0), None, goal_lost=-1), 29 * 4 + 27),
    (obs(None, None, ball_lost=1, goal_lost=1), 318),
    (obs(None, None, ball_lost=-1, goal_lost=-1), 29 * 9 + 27),
    # partially observed (cut by the border): mapped by the observed features
    (obs((35, 250), (40, -240, -0.9)), 29 * 6 + 0),          # half ball at the right edge
    # values on a boundary go to the upper category
    (obs((40.0, -85.3), (100.0, 85.3, 0.1)), 29 * (3 * 1 + 1) + 9 * 2 + 3 * 2 + 2),
]


def test_hand_built_vectors():
    x = np.stack([c[0] for c in CASES])
    got = jax.jit(grid_state)(jnp.asarray(x))
    assert got.dtype == jnp.int32
    np.testing.assert_array_equal(got, [c[1] for c in CASES])


def test_every_category_combination_is_a_distinct_state():
    ball_vals = [(d, u) for u in (-200, 0, 200) for d in (20, 60, 150)]
    goal_vals = [(h, u, o) for u in (-200, 0, 200) for h in (30, 70, 200) for o in (-.5, 0, .5)]
    rows = [obs(b, g) for b, g in itertools.product(ball_vals, goal_vals)]
    rows += [obs(None, g, ball_lost=s) for s in (-1, 1) for g in goal_vals]
    rows += [obs(b, None, goal_lost=s) for b in ball_vals for s in (-1, 1)]
    rows += [obs(None, None, ball_lost=a, goal_lost=b) for a in (-1, 1) for b in (-1, 1)]
    got = np.asarray(grid_state(jnp.asarray(np.stack(rows))))
    assert len(rows) == NUM_GRID_STATES == 319
    assert sorted(got.tolist()) == list(range(319))


def test_batch_shapes_and_labels():
    x = jnp.asarray(np.broadcast_to(CASES[0][0], (2, 3, 9)))
    assert grid_state(x).shape == (2, 3)
    assert state_label(29 * 4 + 16) == "ball(centre,medium) goal(centre,large,front)"
    assert state_label(318) == "ball(lost-right) goal(lost-right)"
    with pytest.raises(ValueError, match="319|318"):
        state_label(319)
    with pytest.raises(ValueError, match=r"\(\.\.\., 9\)"):
        grid_state(jnp.zeros((4, 5)))


def test_boundaries_are_traced_params():
    x = jnp.asarray(obs((60, 0), (150, 0, 0.0)))
    ps = GridParams().replace(ball_size_lower=jnp.array([40.0, 70.0]),
                              ball_size_upper=jnp.array([100.0, 100.0]))
    axes = GridParams(**{k: (0 if k.startswith("ball_size") else None)
                         for k in GridParams.__dataclass_fields__})
    got = jax.vmap(grid_state, in_axes=(None, axes))(x, ps)
    np.testing.assert_array_equal(got, [29 * 4 + 16, 29 * 3 + 16])  # medium -> small


def test_bad_boundaries():
    with pytest.raises(ParamError, match="ball_size_lower"):
        validate(GridParams(ball_size_lower=120.0))
    with pytest.raises(ParamError, match="orient_upper"):
        validate(GridParams(orient_upper=1.5))
