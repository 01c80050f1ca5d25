"""On-line incremental segmentation (Section 2.2) on the two-region linear world.

Truth: the world's change of x is ``step * gain * u`` with gain +1 left of x0 = 0.5
and -1 right of it, so one affine model per region explains every transition; the
only split that helps is x0 = 0.5. With equal gains a single model explains all, so
the two boxes merge back (and a fresh learner never splits).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from toy_worlds import TwoRegionWorld

from vbl.agents.segmentation_learner import (
    IncrementalParams,
    Option,
    greedy_action,
    held_boltzmann_policy,
    init_learner,
    init_option,
    init_run,
    learner_step,
    log_decision,
    monte_carlo_update,
    run_updates,
    update_structure,
)
from vbl.envs.rollout import rollout
from vbl.params import ParamError, validate
from vbl.spaces.incremental import (
    Buffer,
    _greedy_value,
    _sse,
    _stats,
    leaf_of,
    num_states,
    record,
    structure_update,
    td_targets,
)

# as the engine runs them: with 64-bit types on (conftest.engine_precision)
pytestmark = pytest.mark.usefixtures("engine_precision")


ENV = TwoRegionWorld()
M = 1024
# the model-error criterion alone (value-driven splits off; they are tested below)
P = IncrementalParams(max_states=8, buffer_size=M, split_error=1e-5, split_gain=5e-6,
                      merge_tol=1e-6, outcome_weight=0.0, update_every=25,
                      value_split_gain=0.0)


def fill(lr, key, params, noise=0.0):
    """Buffer of M transitions from uniform interior points (no wall clipping)."""
    kx, ka, kn = jax.random.split(key, 3)
    x = jax.random.uniform(kx, (M, 2), jnp.float32, 0.1, 0.85)
    a = jax.random.randint(ka, (M,), 0, 4).astype(jnp.int32)
    dx = jax.vmap(lambda x, a: ENV.delta(x, a, params))(x, a)
    dx = dx + noise * jax.random.normal(kn, dx.shape, jnp.float32)
    y = jnp.concatenate([dx, jnp.zeros((M, 1), jnp.float32)], 1)
    return lr.replace(buf=Buffer(x=x, a=a, y=y, valid=jnp.ones(M, bool),
                                 ptr=jnp.zeros((), jnp.int32), clock=jnp.zeros(M, jnp.int32),
                                 term=jnp.zeros(M, bool)))


@pytest.fixture(scope="module")
def update():
    return jax.jit(lambda lr: update_structure(lr, P))


def boxes(lr):
    act = np.asarray(lr.seg.active)
    return np.asarray(lr.seg.lo)[act], np.asarray(lr.seg.hi)[act]


def assert_cut_at_half(lr):
    """Exactly two boxes: the unit square cut once, at x0 = 0.5."""
    lo, hi = boxes(lr)
    assert len(lo) == 2
    order = np.argsort(lo[:, 0])
    np.testing.assert_allclose(lo[order], [[0.0, 0.0], [0.5, 0.0]])
    np.testing.assert_allclose(hi[order], [[0.5, 1.0], [1.0, 1.0]])


def test_residual_matches_numpy_least_squares():
    rng = np.random.default_rng(0)
    z = np.c_[rng.uniform(size=(50, 2)), np.ones(50)]
    y = rng.normal(size=(50, 3))
    ridge = 1e-3
    w = np.linalg.solve(z.T @ z + ridge * np.eye(3), z.T @ y)
    ref = np.sum((y - z @ w) ** 2) + 0.0
    got = _sse(jnp.asarray(z.T @ z), jnp.asarray(z.T @ y), jnp.asarray(np.sum(y * y)),
               jnp.asarray(50.0), jnp.asarray(ridge))
    # the ridge fit's residual (without the penalty term)
    np.testing.assert_allclose(float(got), ref, rtol=1e-8)


def test_bin_statistics_match_numpy_sums_for_all_boxes_and_candidates():
    """_stats: every box along axis 0, or chosen boxes along every axis, = NumPy sums."""
    lr = init_learner(P, 2, 4)
    seg = lr.seg.replace(lo=lr.seg.lo.at[1].set(jnp.array([0.5, 0.0], jnp.float32)),
                         hi=lr.seg.hi.at[0, 0].set(0.5).at[1].set(1.0),
                         active=lr.seg.active.at[1].set(True))
    buf = fill(lr, jax.random.PRNGKey(3), ENV.default_params).buf
    buf = buf.replace(valid=buf.valid.at[::7].set(False),
                      y=buf.y.at[:, 2].set((jnp.arange(M) % 3 == 0).astype(jnp.float32)))
    x, a, y = (np.asarray(v, np.float64) for v in (buf.x, buf.a, buf.y))
    y[:, 2] *= np.sqrt(0.25)
    z = np.c_[x, np.ones(M)]
    leaf, ok = np.asarray(leaf_of(seg, buf.x)), np.asarray(buf.valid)
    lo, hi = np.asarray(seg.lo)[leaf], np.asarray(seg.hi)[leaf]
    b = np.clip(np.floor(4 * (x - lo) / (hi - lo)), 0, 3)
    every = _stats(seg, buf, 4, 4, 0.25)
    chosen = _stats(seg, buf, 4, 4, 0.25, jnp.array([1, 5, 0]))
    assert every[0].shape == (8, 4, 1, 4, 3, 3) and chosen[3].shape == (3, 4, 2, 4)
    for got, boxes, axes in ((every, range(8), [0]), (chosen, [1, 5, 0], [0, 1])):
        for k, box in enumerate(boxes):
            for act, d, j in np.ndindex(4, len(axes), 4):
                m = ok & (leaf == box) & (a == act) & (b[:, axes[d]] == j)
                ref = (z[m].T @ z[m], z[m].T @ y[m], np.sum(y[m] ** 2), m.sum())
                for g, r in zip(got, ref, strict=True):
                    np.testing.assert_allclose(np.asarray(g[k, act, d, j]), r, rtol=1e-12,
                                               atol=1e-9)


def test_splits_at_region_boundary_and_nowhere_else(update):
    ep = ENV.default_params
    lr = fill(init_learner(P, 2, 4), jax.random.PRNGKey(0), ep, noise=1e-4)
    lr, split, merge = update(lr)
    assert bool(split) and not bool(merge)
    for _ in range(3):                               # refits find nothing more to split
        lr, split, merge = update(lr)
        assert not bool(split) and not bool(merge)
    assert_cut_at_half(lr)
    pts = jnp.array([[0.2, 0.3], [0.49, 0.9], [0.51, 0.1], [1.0, 1.0]], jnp.float32)
    leaf = np.asarray(leaf_of(lr.seg, pts))
    assert leaf[0] == leaf[1] != leaf[2] == leaf[3]
    assert int(lr.splits) == 1


def test_merges_when_regions_become_identical(update):
    ep = ENV.default_params
    lr = fill(init_learner(P, 2, 4), jax.random.PRNGKey(0), ep)
    lr, split, _ = update(lr)
    assert int(num_states(lr.seg)) == 2
    lr = fill(lr, jax.random.PRNGKey(1), ep.replace(gain_right=1.0))
    lr, split, merge = update(lr)
    assert bool(merge) and not bool(split)
    lo, hi = boxes(lr)
    np.testing.assert_allclose(lo, [[0.0, 0.0]])
    np.testing.assert_allclose(hi, [[1.0, 1.0]])
    assert int(lr.merges) == 1


def test_identical_regions_never_split(update):
    ep = ENV.default_params.replace(gain_right=1.0)
    lr = fill(init_learner(P, 2, 4), jax.random.PRNGKey(3), ep, noise=1e-4)
    for _ in range(3):
        lr, split, _ = update(lr)
        assert not bool(split)
    assert int(num_states(lr.seg)) == 1


def test_new_box_inherits_parent_q_or_starts_at_q_init_traced():
    """inherit_q is a traced switch (sweepable): one compiled update serves both values."""
    upd = jax.jit(update_structure)
    lr = fill(init_learner(P, 2, 4), jax.random.PRNGKey(0), ENV.default_params, noise=1e-4)
    lr = lr.replace(q=lr.q.at[0].set(jnp.array([0.7, 0.1, 0.2, 0.3], jnp.float32)))
    for inherit, want in ((True, [0.7, 0.1, 0.2, 0.3]), (False, [-0.3] * 4)):
        out, split, _ = upd(lr, P.replace(inherit_q=inherit, q_init=-0.3))
        assert bool(split)
        new = int(np.flatnonzero(np.asarray(out.seg.active))[-1])      # the new box's slot
        np.testing.assert_allclose(np.asarray(out.q[new]), want, rtol=1e-6)
        np.testing.assert_allclose(np.asarray(out.q[0]), [0.7, 0.1, 0.2, 0.3], rtol=1e-6)


UPDATES = 40
P_RUN = P.replace(temperature=1.0, max_repeat=1)     # explore widely


def _run(key):
    ep = ENV.default_params
    c = init_run(key, ENV, ep, P_RUN, 2, 4)
    return run_updates(c, ENV, lambda t: ep, P_RUN, lambda o: o, UPDATES)


@pytest.fixture(scope="module")
def runs():
    keys = jax.random.split(jax.random.PRNGKey(7), 2)
    single = jax.jit(_run)
    return keys, single, jax.jit(jax.vmap(_run))(keys)


def test_online_run_learns_structure_deterministic_and_batched_equals_looped(runs):
    keys, single, (cb, ob) = runs
    c0, o0 = single(keys[0])
    c0b, o0b = single(keys[0])
    np.testing.assert_array_equal(np.asarray(o0["states"]), np.asarray(o0b["states"]))
    np.testing.assert_array_equal(np.asarray(c0.lr.q), np.asarray(c0b.lr.q))
    assert o0["success"].shape == (UPDATES * P_RUN.update_every,)
    assert c0.lr.q.dtype == jnp.float32 and c0.obs.dtype == jnp.float32
    for i in range(2):
        ci, oi = single(keys[i])
        for a, b in zip(jax.tree_util.tree_leaves((ci, oi)), jax.tree_util.tree_leaves((cb, ob)),
                        strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b)[i], rtol=1e-5, atol=1e-6)
    # the on-line learner segmented (wall clipping adds splits near the walls, so only
    # the count is checked here; the exact boundary is tested on interior data above)
    assert int(num_states(c0.lr.seg)) >= 2 and int(c0.lr.splits) >= 1


def test_bad_thresholds_raise_clear_errors():
    with pytest.raises(ParamError, match="merge_tol"):
        validate(IncrementalParams(merge_tol=1e-4, split_gain=1e-5))
    with pytest.raises(ParamError, match="split_error"):
        validate(IncrementalParams(split_error=-1.0))
    with pytest.raises(ParamError, match="split_gain"):
        validate(IncrementalParams(split_gain=1e-3, split_error=1e-4, merge_tol=0.0))
    with pytest.raises(ParamError, match="temperature"):
        validate(IncrementalParams(temperature=0.0))


def test_partition_update_takes_and_returns_the_q_table(update):
    """vbl.spaces.incremental.structure_update works on arrays (boxes, buffer, Q): the split
    at x0 = 0.5 gives the new box the parent's Q row; the learner's update_structure counts
    it."""
    lr = fill(init_learner(P, 2, 4), jax.random.PRNGKey(0), ENV.default_params, noise=1e-4)
    q = lr.q.at[0].set(jnp.array([0.4, 0.3, 0.2, 0.1], jnp.float32))
    seg, q2, split, merge, vsplit = jax.jit(structure_update)(lr.seg, lr.buf, q, P)
    assert bool(split) and not bool(merge) and not bool(vsplit)
    new = int(np.flatnonzero(np.asarray(seg.active))[-1])
    np.testing.assert_array_equal(np.asarray(q2[new]),
                                  np.array([0.4, 0.3, 0.2, 0.1], np.float32))
    np.testing.assert_array_equal(np.asarray(q2[0]), np.asarray(q[0]))
    counted, _, _ = update(lr.replace(q=q))   # update_structure(., P), jitted
    assert int(counted.splits) == 1 and int(counted.merges) == 0
    np.testing.assert_array_equal(np.asarray(counted.seg.lo), np.asarray(seg.lo))


def _held_option_update(held, x_before, gamma=0.9, alpha=0.5):
    """One learner_step of TwoRegionWorld (gain +1 everywhere, step 0.02, action +x0) that
    ends an action held ``held`` primitives; boxes [0, 0.5) and [0.5, 1] along x0."""

    ep = ENV.default_params.replace(gain_right=1.0)
    p = P.replace(discount=gamma, learning_rate=alpha)
    lr = init_learner(p, 2, 4)
    seg = lr.seg
    lr = lr.replace(seg=seg.replace(hi=seg.hi.at[0, 0].set(0.5).at[1].set(1.0),
                                    lo=seg.lo.at[1, 0].set(0.5),
                                    active=seg.active.at[1].set(True)),
                    q=lr.q.at[0].set(jnp.array([0.2, 0.1, 0.0, 0.0], jnp.float32))
                    .at[1].set(jnp.array([0.8, 0.3, 0.0, 0.0], jnp.float32)))
    x = jnp.array(x_before, jnp.float32)
    st = ToyStateLike(x)
    opt = Option(s0=jnp.int32(0), a=jnp.int32(0), n=jnp.int32(held - 1),
                 active=jnp.asarray(held > 1))
    out, opt2, *_ = learner_step(jax.random.PRNGKey(0), lr, opt, ENV, st, x, ep, p,
                                 lambda o: o)
    return float(out.q[0, 0]), bool(opt2.active)


def ToyStateLike(x):
    from toy_worlds import ToyState
    return ToyState(x, jnp.zeros((), jnp.int32))


@pytest.mark.parametrize("held", [1, 5])
def test_discount_once_per_action_by_hand(held):
    """The action (+x0 from 0.49 into the right box, whose best Q is 0.8) ends after
    ``held`` primitives: Q += alpha (gamma * 0.8 - Q), whatever ``held``."""
    g, a = 0.9, 0.5
    q_act, still = _held_option_update(held, [0.49, 0.3], g, a)
    assert not still                                   # the box changed: the action ended
    assert q_act == pytest.approx(0.2 + a * (g * 0.8 - 0.2), rel=1e-6)


def test_terminal_reward_of_a_held_action_is_not_discounted():
    """Goal on the 4th primitive of an action: target 1 (the discount is per action)."""
    g, a = 0.9, 0.5
    # gain +1, from x = (0.89, 0.95): +x0 reaches x0 >= 0.9 = goal (x1 already >= 0.9),
    # starting in box 1 ([0.5, 1]); reuse the helper's boxes with s0 = 1 via a direct call
    from toy_worlds import ToyState

    ep = ENV.default_params.replace(gain_right=1.0)
    p = P.replace(discount=g, learning_rate=a)
    lr = init_learner(p, 2, 4)
    lr = lr.replace(q=lr.q.at[0, 0].set(0.2))
    x = jnp.array([0.89, 0.95], jnp.float32)
    opt = Option(s0=jnp.int32(0), a=jnp.int32(0), n=jnp.int32(3), active=jnp.asarray(True))
    out, _, _, _, info = learner_step(jax.random.PRNGKey(0), lr, opt, ENV,
                                      ToyState(x, jnp.zeros((), jnp.int32)), x, ep, p,
                                      lambda o: o)
    assert bool(info["terminated"])
    assert float(out.q[0, 0]) == pytest.approx(0.2 + a * (1.0 - 0.2), rel=1e-6)


def test_greedy_action_breaks_ties_at_random_only_with_a_key():
    lr = init_learner(P, 2, 4)
    lr = lr.replace(q=lr.q.at[0].set(jnp.array([0.5, 0.5, 0.1, 0.5], jnp.float32)))
    x = jnp.array([0.3, 0.3], jnp.float32)
    assert int(greedy_action(lr, x)) == 0
    keys = jax.random.split(jax.random.PRNGKey(0), 300)
    got = np.asarray(jax.vmap(lambda k: greedy_action(lr, x, k))(keys))
    assert set(got.tolist()) == {0, 1, 3}                 # only the tied best, each drawn
    assert min(np.bincount(got, minlength=4)[[0, 1, 3]]) > 60


# --- value-driven splits ---------------------------------------------------------------
# Toy world: one affine dynamics everywhere (gain +1), but primitive 0 scores left of
# x0 = 0.5 and primitive 1 right of it (the scoring step's change of x is the world's, so
# the dynamics stay affine; outcome_weight = 0). With Q = 0 everywhere the TD target of a
# transition is 1 if it scored, else 0. Hand-derived greedy values: the whole box has mean
# target 1/2 for primitives 0 and 1 (0 for 2, 3), so v = 1/2; each half has a primitive
# with mean 1, so a cut at x0 = 0.5 gains (1/2 * 1 + 1/2 * 1) - 1/2 = 1/2 per transition;
# a cut at x0 = 0.25 gains 1/4 * 1 + 3/4 * 2/3 - 1/2 = 1/4; cuts along x1 gain ~0.
PV = P.replace(value_split_gain=0.1, value_merge_tol=0.01, value_min_count=10.0)


def scoring_buffer(key, p):
    lr = fill(init_learner(p, 2, 4), key, ENV.default_params.replace(gain_right=1.0),
              noise=1e-4)
    x0, a = lr.buf.x[:, 0], lr.buf.a
    scored = ((a == 0) & (x0 < 0.5)) | ((a == 1) & (x0 >= 0.5))
    return lr.replace(buf=lr.buf.replace(y=lr.buf.y.at[:, 2].set(scored.astype(jnp.float32)),
                                         term=scored))


def test_value_split_cuts_where_the_best_primitive_changes_and_model_error_does_not():
    upd = jax.jit(update_structure)
    lr0 = scoring_buffer(jax.random.PRNGKey(4), PV)
    # the model-error criterion alone (value criterion off): one box, nothing splits
    lr = lr0
    for _ in range(3):
        lr, split, _ = upd(lr, PV.replace(value_split_gain=0.0))
        assert not bool(split)
    assert int(num_states(lr.seg)) == 1
    # the value criterion: exactly one split, at x0 = 0.5, then nothing more
    lr, split, merge = upd(lr0, PV)
    assert bool(split) and not bool(merge)
    assert int(lr.value_splits) == 1 and int(lr.splits) == 1
    for _ in range(3):
        lr, split, merge = upd(lr, PV)
        assert not bool(split) and not bool(merge)      # the merge is vetoed by the value
    assert_cut_at_half(lr)
    # without the veto (merge tolerance above the 1/2 the pair gains by staying apart) the
    # identical models merge the boxes back when nothing splits
    lr_m, split, merge = upd(lr, PV.replace(value_split_gain=0.9, value_merge_tol=0.8))
    assert bool(merge) and not bool(split)


def test_value_split_threshold_above_the_hand_gain_does_not_split():
    upd = jax.jit(update_structure)
    lr = scoring_buffer(jax.random.PRNGKey(4), PV)
    assert not bool(upd(lr, PV.replace(value_split_gain=0.55, value_merge_tol=0.01))[1])
    assert bool(upd(lr, PV.replace(value_split_gain=0.45, value_merge_tol=0.01))[1])


def test_td_targets_follow_the_held_primitive_to_the_box_exit_by_hand():
    """Boxes [0, 0.5) and [0.5, 1] along x0; Q(right box) = (0.8, 0.3, 0, 0). One trial:
    primitive 0 held from x0 = 0.43 in steps of 0.02 (clocks 5, 6, 7, 8: the 4th step
    leaves the left box), then primitive 2 (clock 9) scores, then a new trial's step
    (clock 10) that ends without scoring (term), then the newest one (clock 11)."""
    g = 0.9
    lr = init_learner(P, 2, 4)
    seg = lr.seg
    seg = seg.replace(hi=seg.hi.at[0, 0].set(0.5).at[1].set(1.0),
                      lo=seg.lo.at[1, 0].set(0.5), active=seg.active.at[1].set(True))
    q = lr.q.at[1].set(jnp.array([0.8, 0.3, 0.0, 0.0], jnp.float32))
    buf = lr.buf
    d = jnp.array([0.02, 0.0, 0.0], jnp.float32)
    steps = [([0.43, 0.3], 0, d, 5, False), ([0.45, 0.3], 0, d, 6, False),
             ([0.47, 0.3], 0, d, 7, False), ([0.49, 0.3], 0, d, 8, False),    # exits
             ([0.52, 0.3], 2, jnp.array([0.0, 0.0, 1.0]), 9, True),            # scores
             ([0.10, 0.1], 1, jnp.zeros(3), 10, True),                         # fails
             ([0.20, 0.2], 3, jnp.array([0.0, -0.02, 0.0]), 11, False)]        # newest
    for x, a, y, c, t in steps:
        buf = record(buf, jnp.array(x, jnp.float32), jnp.int32(a), y, jnp.asarray(True), c, t)
    got = np.asarray(td_targets(seg, buf, q, g))[:7]
    want = [g * 0.8] * 4 + [1.0, 0.0, g * 0.0]
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_value_criterion_off_leaves_the_old_updates_unchanged(update):
    """value_split_gain = 0 (off) with any other value settings: the same boxes as the
    model-error criterion alone (the two-region test above)."""
    lr = fill(init_learner(P, 2, 4), jax.random.PRNGKey(0), ENV.default_params, noise=1e-4)
    a, s1, _ = update(lr)
    b, s2, _ = jax.jit(update_structure)(lr, P.replace(value_min_count=1.0,
                                                       value_merge_tol=0.0))
    assert bool(s1) and bool(s2) and int(b.value_splits) == 0
    for u, v in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(u), np.asarray(v))


def test_bad_value_parameters_raise_clear_errors():
    with pytest.raises(ParamError, match="value_merge_tol"):
        validate(IncrementalParams(value_split_gain=0.01, value_merge_tol=0.02))
    with pytest.raises(ParamError, match="value_split_gain"):
        validate(IncrementalParams(value_split_gain=-0.1))
    with pytest.raises(ParamError, match="value_min_count"):
        validate(IncrementalParams(value_min_count=0.0))
    validate(IncrementalParams(value_split_gain=0.0, value_merge_tol=0.02))   # off: fine


def test_cross_fitted_greedy_value_by_hand():
    """Two primitives, 10 transitions in each half of the data. Primitive 0 averages 1 in
    half 0 and 0 in half 1, primitive 1 the reverse: both average 1/2, so the max of the
    means is 1/2; cross-fitted, the primitive chosen on one half scores 0 on the other, so
    the greedy value is 0 (noise does not pay). A primitive under min_count / 2 in one
    half does not count; none qualifying gives -inf."""
    tsum = jnp.array([[[10.0, 0.0], [0.0, 10.0]]], jnp.float64)          # (L=1, A=2, 2)
    tcnt = jnp.full((1, 2, 2), 10.0, jnp.float64)
    assert float(_greedy_value(tsum, tcnt, 10.0, False)[0]) == pytest.approx(0.5)
    assert float(_greedy_value(tsum, tcnt, 10.0, True)[0]) == pytest.approx(0.0)
    # consistent halves: primitive 1 averages 0.8 in both -> 0.8 either way
    tsum2 = jnp.array([[[3.0, 2.0], [8.0, 8.0]]], jnp.float64)
    for xf in (False, True):
        assert float(_greedy_value(tsum2, tcnt, 10.0, xf)[0]) == pytest.approx(0.8)
    few = tcnt.at[0, 1, 0].set(4.0)                                       # 4 < 10 / 2
    assert float(_greedy_value(tsum2, few, 10.0, True)[0]) == pytest.approx(0.25)
    assert float(_greedy_value(tsum2, tcnt, 30.0, True)[0]) == -np.inf


def _mc_learner():
    """Two boxes (x0 < 0.5 | x0 >= 0.5), Monte Carlo updates."""
    p = P.replace(update="monte_carlo", mc_log=4, learning_rate=0.5, mc_discount=0.5)
    lr = init_learner(p, 2, 4)
    seg = lr.seg.replace(lo=lr.seg.lo.at[1].set(jnp.array([0.5, 0.0], jnp.float32)),
                         hi=lr.seg.hi.at[0].set(jnp.array([0.5, 1.0], jnp.float32))
                         .at[1].set(1.0), active=lr.seg.active.at[1].set(True))
    return p, lr.replace(seg=seg)


def test_monte_carlo_update_by_hand():
    """Decisions: box 0 / primitive 2 at clocks 3 and 5, box 1 / primitive 0 at clock 6,
    goal on clock 7, gamma 0.5: returns 1/16, 1/4 (mean 5/32, two updates at alpha 1/2:
    step 3/4) and 1/2 (step 1/2). A failed trial moves towards 0; before the trial ends
    nothing changes; a fifth decision does not fit the 4-slot log."""
    p, lr = _mc_learner()
    log = lr.log
    left, right = jnp.array([0.2, 0.3], jnp.float32), jnp.array([0.7, 0.3], jnp.float32)
    for x, a, c in ((left, 2, 3), (left, 2, 5), (right, 0, 6)):
        log = log_decision(log, jnp.asarray(True), x, a, c)
    log = log_decision(log, jnp.asarray(False), right, 3, 6)               # not a decision
    assert int(log.n) == 3
    q0 = lr.q.at[1, 0].set(0.1)
    mc = jax.jit(monte_carlo_update)
    same, kept = mc(q0, lr.seg, log, jnp.asarray(False), jnp.asarray(False),
                                    jnp.int32(6), p.learning_rate, p.mc_discount)
    np.testing.assert_array_equal(np.asarray(same), np.asarray(q0))
    assert int(kept.n) == 3
    q, emptied = mc(q0, lr.seg, log, jnp.asarray(True), jnp.asarray(True),
                                    jnp.int32(7), p.learning_rate, p.mc_discount)
    want = np.asarray(q0).copy()
    want[0, 2] = 0.75 * (1 / 16 + 1 / 4) / 2
    want[1, 0] = 0.1 + 0.5 * (0.5 - 0.1)
    np.testing.assert_allclose(np.asarray(q), want, rtol=1e-6)
    assert int(emptied.n) == 0
    q_fail, _ = mc(q0, lr.seg, log, jnp.asarray(True), jnp.asarray(False),
                                   jnp.int32(7), p.learning_rate, p.mc_discount)
    assert float(q_fail[1, 0]) == pytest.approx(0.05) and float(q_fail[0, 2]) == 0.0
    for c in range(5):
        log = log_decision(log.replace(n=jnp.int32(0)) if c == 0 else log, jnp.asarray(True),
                           left, 1, c)
    assert int(log.n) == 4 and int(log.clock[-1]) == 3


def test_monte_carlo_learner_step_learns_at_the_trial_end():
    """From x = (0.89, 0.95) in box 1, +x0 scores at once (gain +1): the decision's return
    is 1 and Q(1, +x0) moves by alpha; the Q-learning target would be the same, so the
    step-by-step TD path is checked to be off by a non-terminal step first."""
    from toy_worlds import ToyState

    p, lr = _mc_learner()
    p = p.replace(temperature=1e-3)
    ep = ENV.default_params.replace(gain_right=1.0)
    x = jnp.array([0.6, 0.2], jnp.float32)                  # far from the goal: no score
    lr2, opt, _, _, info = learner_step(jax.random.PRNGKey(1), lr, init_option(), ENV,
                                        ToyState(x, jnp.zeros((), jnp.int32)), x, ep, p,
                                        lambda o: o)
    assert not bool(info["terminated"])
    np.testing.assert_array_equal(np.asarray(lr2.q), np.asarray(lr.q))   # no update yet
    assert int(lr2.log.n) == 1
    x = jnp.array([0.89, 0.95], jnp.float32)
    q = lr.q.at[1, 0].set(0.4)                      # +x0 is the greedy primitive in box 1
    out, _, _, _, info = learner_step(jax.random.PRNGKey(0), lr.replace(q=q), init_option(),
                                      ENV, ToyState(x, jnp.zeros((), jnp.int32)), x, ep, p,
                                      lambda o: o)
    assert bool(info["terminated"]) and bool(info["success"])
    assert float(out.q[1, 0]) == pytest.approx(0.4 + p.learning_rate * (1.0 - 0.4))
    assert int(out.log.n) == 0


def test_held_boltzmann_policy_follows_the_frozen_learner():
    """Box 0 (x0 < 0.5) prefers +x0; box 1 has +x0 and +x1 tied (gain +1 everywhere), so
    at a low temperature the robot, re-deciding every 5 held primitives, mixes the two and
    every start reaches the goal corner; with the preferences towards the walls (-x0, -x1)
    none does."""
    p, lr = _mc_learner()
    p = p.replace(max_repeat=5)
    ep = ENV.default_params.replace(gain_right=1.0, max_steps=1000)
    good = lr.q.at[0, 0].set(1.0).at[1, 0].set(1.0).at[1, 2].set(1.0)

    @jax.jit
    def run(q, t):
        pol, held = held_boltzmann_policy(lr.replace(q=q), p, lambda o: o, t)
        return rollout(ENV, ep, jax.random.PRNGKey(3), pol, 64, 1000, held)[0]

    assert float(run(good, 1e-3).mean()) == 1.0
    bad = lr.q.at[0, 1].set(1.0).at[1, 3].set(1.0)
    assert float(run(bad, 1e-3).mean()) == 0.0


def test_unknown_update_rule_is_a_clear_error():
    with pytest.raises(ParamError, match="update"):
        validate(P.replace(update="sarsa"))
