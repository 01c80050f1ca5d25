"""Off-line action-based construction (Section 2.1) on the 1-D line world.

Hand derivation (step 0.05, goal at p >= 1, primitives F = +step, B = -step, swapped
for p < 0.5): from p in [0.5, 1) holding F reaches the goal -> state F with 1
transition; holding B never reaches it. From p in [0, 0.5) F drives to the wall at 0
(never the goal) while B drives right into the F state -> state B with 2 transitions,
made one iteration later. A third iteration adds nothing. Without the swap a single
state F (1 transition) covers the whole line.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from toy_worlds import LineWorld

from vbl.params import ParamError
from vbl.spaces.action_based import (
    ActionBasedParams,
    CollectParams,
    build_state_map,
    classify,
    collect_experience,
    make_builder,
    num_states,
    policy_action,
    rollout_success,
)

ENV = LineWorld()
CP = CollectParams(episodes_per_action=200, horizon=40)
ABP = ActionBasedParams(max_iterations=4, clusters_per_action=2, start_window=20,
                        coverage=1.0, min_points=10.0, min_reliability=0.8)
F, B = 0, 1


@pytest.fixture(scope="module")
def collect():
    return jax.jit(lambda k, flip: collect_experience(
        ENV, ENV.default_params.replace(flip_below=flip), k, lambda o: o, 2, CP))


@pytest.fixture(scope="module")
def builder():
    return make_builder(ABP)


@pytest.fixture(scope="module")
def flipped(collect, builder):
    exp = collect(jax.random.PRNGKey(0), 0.5)
    return exp, builder(exp, jax.random.PRNGKey(1))


def test_experience_shapes_and_dtypes(flipped):
    exp, _ = flipped
    assert exp.x.shape == (2, 200, 41, 1) and exp.x.dtype == jnp.float32
    assert exp.valid.shape == (2, 200, 41) and exp.goal.shape == (2, 200, 40)
    # B episodes never score; some F episodes do
    assert not bool(exp.goal[B].any()) and bool(exp.goal[F].any())


def test_line_world_with_swap_gives_hand_derived_states(flipped):
    _, sm = flipped
    act = np.asarray(sm.active)
    assert int(num_states(sm)) == 2
    states = np.flatnonzero(act)
    by_action = {int(sm.action[s]): s for s in states}
    assert set(by_action) == {F, B}
    assert int(sm.transitions[by_action[F]]) == 1 and int(sm.order[by_action[F]]) == 0
    assert int(sm.transitions[by_action[B]]) == 2 and int(sm.order[by_action[B]]) == 1
    assert int(sm.iterations) == 3          # the third iteration finds nothing new
    right = jnp.linspace(0.56, 0.97, 12, dtype=jnp.float32)[:, None]
    left = jnp.linspace(0.03, 0.44, 12, dtype=jnp.float32)[:, None]
    assert np.all(np.asarray(classify(sm, right)) == by_action[F])
    assert np.all(np.asarray(classify(sm, left)) == by_action[B])
    assert np.all(np.asarray(policy_action(sm, right)) == F)
    assert np.all(np.asarray(policy_action(sm, left)) == B)
    assert classify(sm, right).dtype == jnp.int32


def test_policy_from_map_reaches_goal(flipped):
    _, sm = flipped
    ep = ENV.default_params.replace(flip_below=0.5)
    ok, n = jax.jit(lambda k: rollout_success(
        ENV, ep, k, lambda o, _: policy_action(sm, o), 64, 60))(jax.random.PRNGKey(5))
    # the slowest start (p ~ 0) needs 10 B + 10 F steps
    assert float(ok.mean()) == 1.0 and int(n.max()) <= 25


def test_line_world_without_swap_is_one_forward_state(collect, builder):
    exp = collect(jax.random.PRNGKey(2), 0.0)
    sm = builder(exp, jax.random.PRNGKey(1))
    assert int(num_states(sm)) == 1
    s = int(np.flatnonzero(np.asarray(sm.active))[0])
    assert int(sm.action[s]) == F and int(sm.transitions[s]) == 1
    xs = jnp.linspace(0.03, 0.97, 20, dtype=jnp.float32)[:, None]
    assert np.all(np.asarray(classify(sm, xs)) == s)


def test_deterministic_and_batched_equals_looped(collect, builder, flipped):
    exp, sm = flipped
    again = builder(exp, jax.random.PRNGKey(1))
    for a, b in zip(jax.tree_util.tree_leaves(sm), jax.tree_util.tree_leaves(again),
                    strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    keys = jax.random.split(jax.random.PRNGKey(9), 2)
    batched = jax.jit(jax.vmap(lambda k: build_state_map(exp, ABP, k)))(keys)
    for i in range(2):
        single = builder(exp, keys[i])
        for a, b in zip(jax.tree_util.tree_leaves(single), jax.tree_util.tree_leaves(batched),
                        strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b)[i], rtol=1e-5, atol=1e-6)


def test_bad_thresholds_raise_clear_errors(flipped):
    exp, _ = flipped
    with pytest.raises(ParamError, match="min_reliability"):
        make_builder(ActionBasedParams(min_reliability=1.5))
    with pytest.raises(ParamError, match="coverage"):
        make_builder(ActionBasedParams(coverage=0.0))
    with pytest.raises(ParamError, match="start_window"):
        make_builder(ABP.replace(start_window=100))(exp, jax.random.PRNGKey(0))
    from vbl.params import validate
    with pytest.raises(ParamError, match="difficulty_lo"):
        validate(CollectParams(difficulty_lo=0.8, difficulty_hi=0.2))


def test_fig5_and_fig9_compare_with_grid_shootings_own_config():
    """The grid baseline of Figures 5 and 9 is grid_shooting's default config by reference,
    except the evaluation's start difficulty, pinned to 0.1 (grid_shooting's own task is
    fully random starts); Figure 9 evaluates at its training episodes' difficulty."""
    from vbl.engine.registry import get

    gs = get("grid_shooting").default_config
    for name in ("fig5_action_based", "fig9_incremental"):
        g = get(name).default_config.grid
        assert g.agent == gs.agent and g.grid == gs.grid, name
        assert g.train.replace(eval_difficulty=gs.train.eval_difficulty) == gs.train, name
        assert g.train.eval_difficulty == pytest.approx(0.1), name
    f9 = get("fig9_incremental").default_config
    assert f9.env.start_difficulty == pytest.approx(f9.grid.train.eval_difficulty)
