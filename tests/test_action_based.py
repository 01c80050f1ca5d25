"""Experience collection of the off-line, action-based construction (Section 2.1) on the
1-D line world (step 0.05, goal at p >= 1, primitives F = +step, B = -step, swapped for
p < 0.5): F episodes from p >= 0.5 score, B episodes never do; the construction itself is
tested in test_action_cells.py."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from toy_worlds import line_world_collector

from vbl.params import ParamError, validate
from vbl.spaces.action_based import ExperienceParams

CP = ExperienceParams(episodes_per_action=200, horizon=40)
F, B = 0, 1


@pytest.fixture(scope="module")
def flipped():
    return line_world_collector(CP.episodes_per_action, CP.horizon)(jax.random.PRNGKey(0), 0.5)


def test_experience_shapes_and_dtypes(flipped):
    exp = flipped
    assert exp.x.shape == (2, 200, 41, 1) and exp.x.dtype == jnp.float32
    assert exp.valid.shape == (2, 200, 41) and exp.goal.shape == (2, 200, 40)
    # B episodes never score; F episodes score exactly from the starts p >= 0.5 (at most
    # 10 steps of 0.05 to the goal, well within the horizon); below, F backs into the wall
    assert not bool(exp.goal[B].any())
    start = np.asarray(exp.x[F, :, 0, 0])
    np.testing.assert_array_equal(np.asarray(exp.goal[F].any(axis=-1)), start >= 0.5)


def test_bad_collection_settings_raise_clear_errors():
    with pytest.raises(ParamError, match="difficulty_lo"):
        validate(ExperienceParams(difficulty_lo=0.8, difficulty_hi=0.2))


def test_fig5_and_fig9_compare_with_grid_shootings_own_config():
    """The grid baseline of Figures 5 and 9 is grid_shooting's default config (the preset of
    vbl.programs.baselines), except the evaluation's start difficulty, pinned to 0.1
    (grid_shooting's own task is fully random starts), and, for Figure 9, the budget (robots,
    chunks: equal experience), a curve point every chunk and an evaluation of one chunk
    (its episodes last 150 primitives) over as many starts as grid_shooting's (rounds x
    robots); Figure 9 evaluates at its training episodes' difficulty."""
    from vbl.engine.registry import get

    gs = get("grid_shooting").default_config
    for name in ("fig5_action_based", "fig9_incremental"):
        g = get(name).default_config.baseline
        budget = dict(num_envs=gs.agent.num_envs), dict(num_chunks=gs.train.num_chunks)
        if name == "fig9_incremental":
            assert g.train.eval_every == 1 and g.train.eval_chunks * g.agent.chunk_steps >= 150
            assert (g.train.eval_rounds * g.agent.num_envs
                    >= gs.train.eval_rounds * gs.agent.num_envs / 2)
            budget[1].update(eval_every=gs.train.eval_every, eval_chunks=gs.train.eval_chunks,
                             eval_rounds=gs.train.eval_rounds)
        assert g.agent.replace(**budget[0]) == gs.agent and g.grid == gs.grid, name
        assert g.train.replace(eval_difficulty=gs.train.eval_difficulty, **budget[1]) == \
            gs.train, name
        assert g.train.eval_difficulty == pytest.approx(0.1), name
    f5 = get("fig5_action_based").default_config
    assert (f5.baseline.agent.num_envs, f5.baseline.train.num_chunks) == (gs.agent.num_envs,
                                                                  gs.train.num_chunks)
    f9 = get("fig9_incremental").default_config
    assert f9.env.start_difficulty == pytest.approx(f9.baseline.train.eval_difficulty)


def test_pattern_of_reads_categorical_digits():
    from vbl.spaces.action_based import pattern_of
    x = jnp.asarray([[0.3, 0.0, 0.0], [0.3, 0.5, 0.0], [0.9, 1.0, 0.5], [0.1, 0.0, 1.0],
                     [0.2, 1.0, 1.0]], jnp.float32)
    # digits (round(2 v)) of the last two features, base 3, first digit least significant
    np.testing.assert_array_equal(np.asarray(pattern_of(x, 2, 3)), [0, 1, 5, 6, 8])
    np.testing.assert_array_equal(np.asarray(pattern_of(x, 0, 3)), [0, 0, 0, 0, 0])
    assert pattern_of(x, 2, 3).dtype == jnp.int32


def test_fig5_categorical_dims_need_lost_side_features():
    """Figure 5 treats the two lost-side features as categorical; without them (5 features)
    that setting is refused with a clear error before anything is compiled."""
    from vbl.engine.registry import get

    exp = get("fig5_action_based")
    cfg = exp.default_config
    assert cfg.cells.categorical_dims == 2 and cfg.features.lost_sides
    bad = cfg.replace(features=cfg.features.replace(lost_sides=False))
    with pytest.raises(ParamError, match="categorical_dims"):
        exp.make_program(bad)
