"""Closed-loop refinement of a cell map (vbl.spaces.cell_refine).

Independent truths: the 1-D line world's hand-derived policy (F on p >= 0.5, B below,
where the primitives swap direction) is recovered from a map corrupted to "B everywhere";
the unit next to the goal scores in one decision; the decision statistics equal a loop
over the episodes written from the definition.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from toy_worlds import LineWorld, line_world_collector

from vbl.params import ParamError, validate
from vbl.spaces.action_cells import (
    CellMapParams,
    cell_index,
    cell_policy_action,
    make_cell_builder,
)
from vbl.spaces.cell_refine import (
    RefineParams,
    decision_statistics,
    initial_units,
    make_refiner,
    num_refined_states,
    num_refined_units,
    refine_cell_map,
    refined_policy_action,
)

# as the engine runs them: with 64-bit types on (conftest.engine_precision)
pytestmark = pytest.mark.usefixtures("engine_precision")


ENV = LineWorld()
EP = ENV.default_params.replace(flip_below=0.5)
LINE = CellMapParams(bins=(20,), seen_feature=(-1,), spacing="uniform", categorical_dims=0,
                     start_window=20, max_iterations=4, min_points=5.0, min_reliability=0.8)
RP = RefineParams(iterations=20, episodes=256, horizon=60, epsilon=0.3, min_visits=5.0,
                  units="cells")
F, B = 0, 1
RIGHT = jnp.linspace(0.56, 0.97, 12, dtype=jnp.float32)[:, None]
LEFT = jnp.linspace(0.03, 0.44, 12, dtype=jnp.float32)[:, None]


@pytest.fixture(scope="module")
def corrupted():
    """The hand-derived line-world map with every labelled cell's primitive set to B."""
    exp = line_world_collector(200, 40)(jax.random.PRNGKey(0), 0.5)
    cm = make_cell_builder(LINE)(exp)
    b_state = int(np.flatnonzero(np.asarray(cm.active) & (np.asarray(cm.action) == B))[0])
    return cm.replace(cell_state=jnp.where(cm.cell_state >= 0, b_state, cm.cell_state))


@pytest.fixture(scope="module")
def refined(corrupted):
    return make_refiner(ENV, lambda o: o, RP)(EP, jax.random.PRNGKey(3), corrupted)


def test_refinement_recovers_the_hand_derived_policy(corrupted, refined):
    assert np.all(np.asarray(cell_policy_action(corrupted, RIGHT)) == B)  # the corrupted start
    assert np.all(np.asarray(refined_policy_action(corrupted, refined, RIGHT)) == F)
    assert np.all(np.asarray(refined_policy_action(corrupted, refined, LEFT)) == B)
    assert float(refined.train_success[-1]) > float(refined.train_success[0])


def test_unit_next_to_the_goal_scores_in_one_decision(corrupted, refined):
    top = int(refined.unit_of[cell_index(corrupted, jnp.array([0.97], jnp.float32))])
    below = int(refined.unit_of[cell_index(corrupted, jnp.array([0.92], jnp.float32))])
    assert int(refined.transitions[top]) == 1 and int(refined.transitions[below]) == 2
    assert int(refined.state[top]) == 1 * ENV.num_actions + F
    # one F state per transition count on the right, B states on the left: at least 2
    assert 2 <= int(num_refined_states(refined, ENV.num_actions, RP.max_transitions)) <= 2 * 12
    assert int(num_refined_units(refined)) == 20          # every one of the 20 cells was tried
    # F in the top unit scores in the decision's own step (discount^0 = 1), but for the
    # few points within a float rounding of the cell's lower edge (one more step: 0.98)
    assert float(refined.score[top, F]) > RP.discount


def test_policy_reaches_goal_from_everywhere(corrupted, refined):
    from vbl.envs.rollout import rollout, stateless

    ok, _ = jax.jit(lambda k: rollout(
        ENV, EP, k, stateless(lambda o, _: refined_policy_action(corrupted, refined, o)),
        256, 60))(jax.random.PRNGKey(9))
    assert float(ok.mean()) >= 0.95   # only starts in the cell straddling p = 0.5 may fail


def _stats_reference(unit, action, decided, success, greedy, discount, n_u, n_a):
    """decision_statistics from its definition, one decision at a time."""
    s_sum, visits = np.zeros((n_u, n_a)), np.zeros((n_u, n_a))
    t_sum, t_cnt = np.zeros(n_u), np.zeros(n_u)
    for e in range(unit.shape[0]):
        hits = np.flatnonzero(success[e])
        for t in np.flatnonzero(decided[e]):
            u, a = unit[e, t], action[e, t]
            visits[u, a] += 1
            later = hits[hits >= t]
            if later.size:
                s_sum[u, a] += discount ** (later[0] - t)
                if greedy[e, t]:
                    t_sum[u] += decided[e, t:later[0] + 1].sum()
                    t_cnt[u] += 1
    return s_sum, visits, t_sum, t_cnt


def test_decision_statistics_match_loop_reference():
    rng = np.random.default_rng(0)
    n_e, n_t, n_u, n_a = 40, 25, 6, 3
    unit = rng.integers(0, n_u, (n_e, n_t)).astype(np.int32)
    action = rng.integers(0, n_a, (n_e, n_t)).astype(np.int32)
    end = rng.integers(5, n_t, n_e)
    alive = np.arange(n_t)[None] <= end[:, None]
    scored = rng.random(n_e) < 0.6
    success = (np.arange(n_t)[None] == end[:, None]) & scored[:, None]
    decided = (rng.random((n_e, n_t)) < 0.5) & alive
    greedy = rng.random((n_e, n_t)) < 0.7
    got = jax.jit(decision_statistics, static_argnums=(6, 7))(
        unit, action, decided, success, greedy, 0.9, n_u, n_a)
    want = _stats_reference(unit, action, decided, success, greedy, 0.9, n_u, n_a)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(np.asarray(g), w, rtol=1e-5, atol=1e-6)


def test_deterministic_and_batched_equals_looped(corrupted, refined):
    p = RP.replace(iterations=4, episodes=64)
    one = make_refiner(ENV, lambda o: o, p)
    keys = jax.random.split(jax.random.PRNGKey(4), 2)
    eps = jnp.array([0.3, 0.1], jnp.float32)
    batched = jax.jit(jax.vmap(lambda k, e: refine_cell_map(
        ENV, EP, k, lambda o: o, corrupted, p.replace(epsilon=e))))(keys, eps)
    for i in range(2):
        single = one(EP, keys[i], corrupted) if i == 0 else make_refiner(
            ENV, lambda o: o, p.replace(epsilon=0.1))(EP, keys[i], corrupted)
        for a, b in zip(jax.tree_util.tree_leaves(single), jax.tree_util.tree_leaves(batched),
                        strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b)[i], rtol=1e-6)
    again = one(EP, keys[0], corrupted)
    np.testing.assert_array_equal(np.asarray(again.policy), np.asarray(batched.policy)[0])


def test_labelled_units_share_one_remainder_per_pattern():
    exp = line_world_collector(200, 40)(jax.random.PRNGKey(0), 0.5)
    cm = make_cell_builder(LINE.replace(min_reliability=0.99, max_iterations=1))(exp)
    unit_of, pol = initial_units(cm, "labelled")
    lab = np.asarray(cm.cell_state) >= 0
    n_cells = lab.size
    assert pol.shape == (n_cells + 1,)                      # one categorical pattern
    np.testing.assert_array_equal(np.asarray(unit_of)[lab], np.flatnonzero(lab))
    assert np.all(np.asarray(unit_of)[~lab] == n_cells)
    assert int(pol[n_cells]) == int(cm.fallback[0])


def test_bad_settings_raise_clear_errors():
    with pytest.raises(ParamError, match="epsilon"):
        validate(RP.replace(epsilon=1.5))
    with pytest.raises(ParamError, match="units"):
        validate(RP.replace(units="states"))
    with pytest.raises(ParamError, match="difficulty_lo"):
        validate(RP.replace(difficulty_lo=0.5, difficulty_hi=0.2))
    with pytest.raises(ParamError, match="min_visits"):
        make_refiner(ENV, lambda o: o, RP.replace(min_visits=0.0))


def test_fig5_refines_by_default_and_checks_the_section():
    from vbl.engine.registry import get

    exp = get("fig5_action_based")
    cfg = exp.default_config
    assert cfg.refine.iterations > 0 and cfg.refine.units == "labelled"
    with pytest.raises(ParamError, match="refine"):
        exp.make_program(cfg.replace(refine=cfg.refine.replace(epsilon=-0.1)))
