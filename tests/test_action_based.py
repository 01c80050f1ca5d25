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
from toy_worlds import LineWorld, assert_line_world_swap_map, line_world_collector

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
    return line_world_collector(CP.episodes_per_action, CP.horizon)


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
    assert_line_world_swap_map(sm, num_states, classify, policy_action)
    assert int(sm.iterations) == 3          # the third iteration finds nothing new


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
        for name in single.__dataclass_fields__:
            a, b = getattr(single, name), getattr(batched, name)
            if not isinstance(a, jax.Array):
                assert a == b, name             # static fields
                continue
            # a reliability is a count ratio: float reduction order may move one boundary
            # point of ~1,000 in or out of an ellipsoid
            tol = 2e-3 if name == "ell_reliability" else 1e-6
            np.testing.assert_allclose(np.asarray(a), np.asarray(b)[i], rtol=1e-5, atol=tol,
                                       err_msg=name)


def test_bad_thresholds_raise_clear_errors(flipped):
    exp, _ = flipped
    with pytest.raises(ParamError, match="min_reliability"):
        make_builder(ActionBasedParams(min_reliability=1.5))
    with pytest.raises(ParamError, match="coverage"):
        make_builder(ActionBasedParams(coverage=0.0))
    with pytest.raises(ParamError, match="supersede"):
        make_builder(ActionBasedParams(supersede=True))          # needs rank="value"
    with pytest.raises(ParamError, match="rank"):
        make_builder(ActionBasedParams(rank="nearest"))
    with pytest.raises(ParamError, match="start_window"):
        make_builder(ABP.replace(start_window=100))(exp, jax.random.PRNGKey(0))
    from vbl.params import validate
    with pytest.raises(ParamError, match="difficulty_lo"):
        validate(CollectParams(difficulty_lo=0.8, difficulty_hi=0.2))


def test_fig5_and_fig9_compare_with_grid_shootings_own_config():
    """The grid baseline of Figures 5 and 9 is grid_shooting's default config by reference,
    except the evaluation's start difficulty, pinned to 0.1 (grid_shooting's own task is
    fully random starts), and, for Figure 9, the budget (one robot, equal experience) and a
    curve point every chunk; Figure 9 evaluates at its training episodes' difficulty."""
    import sys

    from vbl.engine.registry import get

    gs = get("grid_shooting").default_config
    get("fig9_incremental")
    f9m = sys.modules["vbl_experiments.fig9_incremental"]
    for name in ("fig5_action_based", "fig9_incremental"):
        g = get(name).default_config.grid
        budget = dict(num_envs=gs.agent.num_envs), dict(num_chunks=gs.train.num_chunks)
        if name == "fig9_incremental":
            assert g.train.eval_every == 1
            budget[1]["eval_every"] = gs.train.eval_every
            assert (g.agent.num_envs, g.train.num_chunks) == (f9m.GRID_ENVS, f9m.GRID_CHUNKS)
        assert g.agent.replace(**budget[0]) == gs.agent and g.grid == gs.grid, name
        assert g.train.replace(eval_difficulty=gs.train.eval_difficulty, **budget[1]) == \
            gs.train, name
        assert g.train.eval_difficulty == pytest.approx(0.1), name
    f9 = get("fig9_incremental").default_config
    assert f9.env.start_difficulty == pytest.approx(f9.grid.train.eval_difficulty)


def test_pattern_of_reads_categorical_digits():
    from vbl.spaces.action_based import pattern_of
    x = jnp.asarray([[0.3, 0.0, 0.0], [0.3, 0.5, 0.0], [0.9, 1.0, 0.5], [0.1, 0.0, 1.0],
                     [0.2, 1.0, 1.0]], jnp.float32)
    # digits (round(2 v)) of the last two features, base 3, first digit least significant
    np.testing.assert_array_equal(np.asarray(pattern_of(x, 2, 3)), [0, 1, 5, 6, 8])
    np.testing.assert_array_equal(np.asarray(pattern_of(x, 0, 3)), [0, 0, 0, 0, 0])
    assert pattern_of(x, 2, 3).dtype == jnp.int32


def test_kmeans_groups_never_mix():
    """Two groups at overlapping positions: with one cluster per group each centre is its
    own group's mean (hand values), whatever the distances say."""
    from vbl.spaces.ellipsoids import kmeans
    pts = jnp.asarray([[0.10], [0.20], [0.15], [0.90]], jnp.float32)
    grp = jnp.asarray([0, 0, 1, 1], jnp.int32)
    mask = jnp.ones(4, bool)
    c, a = kmeans(jax.random.PRNGKey(0), pts, mask, 1, 5, grp, 2)
    np.testing.assert_allclose(np.asarray(c)[:, 0], [0.15, 0.525], rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(a), [0, 0, 1, 1])


def _flag_features(o):
    """Line world position plus a categorical 'facing' flag (1 where the primitives are not
    swapped, p >= 0.5; 0 below)."""
    return jnp.concatenate([o, (o >= 0.5).astype(jnp.float32)])


def test_categorical_feature_states_hold_only_their_pattern():
    """With the swap flag as a categorical feature (2 levels) the hand-derived states come
    out again (F1 where the flag is 1, B2 where it is 0), and an ellipsoid never holds a
    point of the other pattern: (p, flag) with the flag contradicting p is in no state."""
    exp = jax.jit(lambda k: collect_experience(
        ENV, ENV.default_params.replace(flip_below=0.5), k, _flag_features, 2, CP))(
        jax.random.PRNGKey(0))
    p = ABP.replace(categorical_dims=1, categorical_levels=2)
    sm = make_builder(p)(exp, jax.random.PRNGKey(1))
    assert int(num_states(sm)) == 2
    by_action = {int(sm.action[s]): s for s in np.flatnonzero(np.asarray(sm.active))}
    assert int(sm.transitions[by_action[F]]) == 1 and int(sm.transitions[by_action[B]]) == 2
    ea = np.asarray(sm.ell_active)
    pat = np.asarray(sm.ell_pattern)[ea]
    st = np.asarray(sm.ell_state)[ea]
    # F's ellipsoids hold only flag-1 points; B's are flag-0 ones (plus, possibly, a rim
    # ellipsoid of flag-1 points just right of 0.5 that F1's ellipsoid left uncovered: B
    # from there steps into B2 at once, so they belong to B2 too)
    assert set(pat[st == by_action[F]]) == {1} and 0 in set(pat[st == by_action[B]])
    right = jnp.linspace(0.56, 0.97, 12, dtype=jnp.float32)[:, None]
    left = jnp.linspace(0.03, 0.44, 12, dtype=jnp.float32)[:, None]
    ones, zeros = jnp.ones_like(right), jnp.zeros_like(right)
    assert np.all(np.asarray(classify(sm, jnp.concatenate([right, ones], 1))) == by_action[F])
    assert np.all(np.asarray(classify(sm, jnp.concatenate([left, zeros], 1))) == by_action[B])
    # a contradicting flag: in no state (away from 0.5, where an ellipsoid of the other
    # pattern may reach a little past its members, e.g. B2's to p = 0.56 with flag 0)
    far_right = jnp.linspace(0.7, 0.97, 8, dtype=jnp.float32)[:, None]
    far_left = jnp.linspace(0.03, 0.3, 8, dtype=jnp.float32)[:, None]
    z8, o8 = jnp.zeros_like(far_right), jnp.ones_like(far_right)
    assert np.all(np.asarray(classify(sm, jnp.concatenate([far_right, z8], 1))) == -1)
    assert np.all(np.asarray(classify(sm, jnp.concatenate([far_left, o8], 1))) == -1)
    with pytest.raises(ParamError, match="categorical_dims"):
        make_builder(p)(exp.replace(x=exp.x[..., :1]), jax.random.PRNGKey(1))


def test_ellipsoid_value_matches_numpy_reference(collect):
    """Without the swap, every F start point reaches the goal directly: the F1 ellipsoids'
    value is the mean over the F start points inside them of discount^(steps after the
    point until the scoring step), computed here from the raw experience."""
    exp = collect(jax.random.PRNGKey(2), 0.0)
    gam = 0.9
    sm = make_builder(ABP.replace(discount=gam))(exp, jax.random.PRNGKey(1))
    x, valid, goal = (np.asarray(exp.x)[F], np.asarray(exp.valid)[F], np.asarray(exp.goal)[F])
    w = ABP.start_window
    # steps from t to the first goal step g of its episode (inf: never)
    g_idx = np.where(goal.any(1), goal.argmax(1), 10 ** 6)
    t = np.arange(w)[None]
    val = np.where(t <= g_idx[:, None], gam ** (g_idx[:, None] - t).astype(float), 0.0)
    val = np.where(g_idx[:, None] < 10 ** 6, val, 0.0)
    xs, ok = x[:, :w, 0], valid[:, :w]
    ea = np.flatnonzero(np.asarray(sm.ell_active))
    assert len(ea) >= 1
    for e in ea:
        c, m = np.asarray(sm.centre)[e, 0], np.asarray(sm.shape)[e, 0, 0]
        inside = ok & ((xs - c) ** 2 * m <= 1.0)
        assert inside.sum() > 10
        np.testing.assert_allclose(float(sm.ell_value[e]), val[inside].mean(), rtol=1e-4)
        np.testing.assert_allclose(float(sm.ell_reliability[e]), 1.0)


def test_value_rank_gives_the_same_hand_derived_map(flipped):
    """Ranking overlaps by value instead of transitions changes no state of the line world:
    F1 on [0.5, 1), B2 on [0, 0.5), and the values are ordered as derived by hand (every F1
    point scores within 10 steps, a B2 point needs its B steps first: lower value)."""
    exp, _ = flipped
    sm = make_builder(ABP.replace(rank="value", discount=0.9))(exp, jax.random.PRNGKey(1))
    assert int(num_states(sm)) == 2 and sm.rank == "value"
    by_action = {int(sm.action[s]): s for s in np.flatnonzero(np.asarray(sm.active))}
    right = jnp.linspace(0.56, 0.97, 12, dtype=jnp.float32)[:, None]
    left = jnp.linspace(0.03, 0.44, 12, dtype=jnp.float32)[:, None]
    assert np.all(np.asarray(classify(sm, right)) == by_action[F])
    assert np.all(np.asarray(classify(sm, left)) == by_action[B])
    ea = np.asarray(sm.ell_active)
    val, st = np.asarray(sm.ell_value)[ea], np.asarray(sm.ell_state)[ea]
    assert val[st == by_action[F]].min() > val[st == by_action[B]].max() > 0.0
    assert val.max() <= 1.0


def test_fig5_categorical_dims_need_lost_side_features():
    """Figure 5 treats the two lost-side features as categorical; without them (5 features)
    that setting is refused with a clear error before anything is compiled."""
    from vbl.engine.registry import get

    exp = get("fig5_action_based")
    cfg = exp.default_config
    assert cfg.build.categorical_dims == 2 and cfg.features.lost_sides
    # chain reliability and the time rank are Figure 5's construction
    assert cfg.build.chain_reliability and cfg.build.rank == "time"
    assert cfg.build.min_reliability == pytest.approx(0.4)
    bad = cfg.replace(features=cfg.features.replace(lost_sides=False))
    with pytest.raises(ParamError, match="categorical_dims"):
        exp.make_program(bad)


def _moving(state):
    """Line-world 'speed': 1 on [0.5, 0.75) (the points to drop as start points), else 0."""
    p = state.x[0]
    return ((p >= 0.5) & (p < 0.75)).astype(jnp.float32)


def test_collect_records_speed_and_rest_filter_drops_exactly_the_moving_points():
    """speed_fn is recorded at every point (here 1 exactly where 0.5 <= p < 0.75). With
    start_max_speed 0.5 those points are no start points: F1 comes only from F points at
    p >= 0.75 (its ellipsoid reaches at most ~0.12 below them), and B, which oscillates
    just below 0.5, never reaches it -> one state, and p in [0.5, 0.7] is in none. With
    all speeds 0 the filter changes nothing (the map equals the unfiltered one)."""
    ep = ENV.default_params.replace(flip_below=0.5)
    exp = jax.jit(lambda k: collect_experience(ENV, ep, k, lambda o: o, 2, CP, _moving))(
        jax.random.PRNGKey(0))
    x, sp, valid = (np.asarray(a) for a in (exp.x[..., 0], exp.speed, exp.valid))
    assert exp.speed.shape == exp.valid.shape and exp.speed.dtype == jnp.float32
    np.testing.assert_array_equal(sp[valid], ((x >= 0.5) & (x < 0.75))[valid])
    p = ABP.replace(start_max_speed=0.5)
    sm = make_builder(p)(exp, jax.random.PRNGKey(1))
    assert int(num_states(sm)) == 1
    s = int(np.flatnonzero(np.asarray(sm.active))[0])
    assert int(sm.action[s]) == F and int(sm.transitions[s]) == 1
    mid = jnp.linspace(0.5, 0.7, 9, dtype=jnp.float32)[:, None]
    top = jnp.linspace(0.8, 0.97, 9, dtype=jnp.float32)[:, None]
    assert np.all(np.asarray(classify(sm, mid)) == -1)
    assert np.all(np.asarray(classify(sm, top)) == s)
    # speeds all 0: the same map as without the filter, bit for bit
    still = exp.replace(speed=jnp.zeros_like(exp.speed))
    a, b = make_builder(p)(still, jax.random.PRNGKey(1)), make_builder(ABP)(still,
                                                                           jax.random.PRNGKey(1))
    for u, v in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(u), np.asarray(v))


def _twin_experience(n=60, t_len=40, step=0.05):
    """Hand-made line experience (A = 2, D = 1). F (group 0): pairs of identical episodes
    walking right from p0 in [0.5, 0.95); the first of a pair scores on the step that
    crosses 1, its twin ends there without scoring. B (group 1): episodes walking right
    from p0 in [0, 0.45) into the F region, never scoring. So every F1 ellipsoid holds
    twins in equal numbers (chain value exactly 0.5) and every B start point reaches F1."""
    x = np.zeros((2, n, t_len + 1, 1), np.float32)
    valid = np.zeros((2, n, t_len + 1), bool)
    goal = np.zeros((2, n, t_len), bool)
    for i in range(n):
        p0 = 0.5 + 0.45 * (i // 2) / (n // 2)
        path = p0 + step * np.arange(t_len + 1)
        tg = int(np.argmax(path >= 1.0)) - 1               # the step that crosses 1
        x[0, i, :, 0], valid[0, i, :tg + 1] = np.minimum(path, 1.0), True
        goal[0, i, tg] = i % 2 == 0
        q = 0.45 * i / n + step * np.arange(t_len + 1)
        x[1, i, :, 0], valid[1, i] = np.minimum(q, 1.0), q < 0.95
    from vbl.spaces.action_based import Experience
    return Experience(x=jnp.asarray(x), valid=jnp.asarray(valid), goal=jnp.asarray(goal),
                      speed=jnp.zeros(valid.shape, jnp.float32))


def test_chain_reliability_counts_the_reached_states_chain_value():
    """Hand truth on the twin experience: F1's reliability is 0.5 (half of its start points
    score); every B start point reaches F1, so B2's reliability is 1 when reaching counts
    1, and 0.5 (the chain value of the F1 ellipsoid it reaches) with chain_reliability."""
    exp = _twin_experience()
    p = ABP.replace(min_reliability=0.4)
    for chain, b_rel in ((False, 1.0), (True, 0.5)):
        sm = make_builder(p.replace(chain_reliability=chain))(exp, jax.random.PRNGKey(1))
        assert int(num_states(sm)) == 2, chain
        ea = np.asarray(sm.ell_active)
        act = np.asarray(sm.action)[np.asarray(sm.ell_state)][ea]
        rel = np.asarray(sm.ell_reliability)[ea]
        np.testing.assert_allclose(rel[act == F], 0.5, rtol=1e-6)
        np.testing.assert_allclose(rel[act == B], b_rel, rtol=1e-6)
    # at 0.6 the chain (0.5) keeps nothing
    sm = make_builder(p.replace(min_reliability=0.6, chain_reliability=True))(
        exp, jax.random.PRNGKey(1))
    assert int(num_states(sm)) == 0


def test_ellipsoid_time_matches_numpy_reference(collect):
    """Without the swap every F start point scores directly: an F1 ellipsoid's expected
    time is the mean over its reaching F start points of (scoring step - t + 1)."""
    exp = collect(jax.random.PRNGKey(2), 0.0)
    sm = make_builder(ABP)(exp, jax.random.PRNGKey(1))
    x, valid, goal = (np.asarray(exp.x)[F], np.asarray(exp.valid)[F], np.asarray(exp.goal)[F])
    w = ABP.start_window
    scores = goal.any(1)
    g_idx = np.where(scores, goal.argmax(1), -1)
    t = np.arange(w)[None]
    reach = scores[:, None] & (t <= g_idx[:, None]) & valid[:, :w]
    tm = (g_idx[:, None] - t + 1).astype(float)
    xs = x[:, :w, 0]
    ea = np.flatnonzero(np.asarray(sm.ell_active))
    assert len(ea) >= 1
    for e in ea:
        c, m = np.asarray(sm.centre)[e, 0], np.asarray(sm.shape)[e, 0, 0]
        inside = reach & ((xs - c) ** 2 * m <= 1.0)
        np.testing.assert_allclose(float(sm.ell_time[e]), tm[inside].mean(), rtol=1e-4)


def test_time_rank_prefers_the_faster_containing_state():
    """Two states whose ellipsoids both contain x = 0.5: state 0 (1 transition, 30 expected
    primitives), state 1 (2 transitions, 10 primitives). 'transitions' picks state 0,
    'time' state 1; outside both: -1."""
    from vbl.spaces.action_based import StateMap
    f = jnp.float32
    sm = StateMap(centre=jnp.asarray([[0.45], [0.55]], f), shape=jnp.asarray([[[100.0]],
                  [[100.0]]], f), ell_active=jnp.ones(2, bool),
                  ell_state=jnp.asarray([0, 1], jnp.int32), ell_pattern=jnp.zeros(2, jnp.int32),
                  ell_reliability=jnp.ones(2, f), ell_value=jnp.zeros(2, f),
                  ell_time=jnp.asarray([30.0, 10.0], f), action=jnp.asarray([F, B], jnp.int32),
                  transitions=jnp.asarray([1, 2], jnp.int32), order=jnp.asarray([0, 1], jnp.int32),
                  active=jnp.ones(2, bool), iterations=jnp.asarray(2, jnp.int32))
    x = jnp.asarray([[0.5], [0.9]], f)
    np.testing.assert_array_equal(np.asarray(classify(sm, x)), [0, -1])
    np.testing.assert_array_equal(np.asarray(classify(sm.replace(rank="time"), x)), [1, -1])
