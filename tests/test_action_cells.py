"""Action-based construction on quantile cells (vbl.spaces.action_cells).

Hand derivation on the 1-D line world (as in test_action_based.py; step 0.05, goal at
p >= 1, F and B swapped for p < 0.5): holding F from p in [0.5, 1) scores -> cells there
form state F with 1 transition (iteration 0); from p in [0, 0.5) only B reaches them ->
state B with 2 transitions (iteration 1). Without the swap one F state covers the line.
A loop-based NumPy reference checks the labelling on random experience.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from toy_worlds import LineWorld, assert_line_world_swap_map, line_world_collector

from vbl.envs.rollout import rollout, stateless
from vbl.params import ParamError
from vbl.spaces.action_based import Experience, ExperienceParams
from vbl.spaces.action_cells import (
    CellMapParams,
    build_cell_map,
    cell_index,
    cell_policy_action,
    classify_cells,
    make_cell_builder,
    num_cell_states,
)

ENV = LineWorld()
CP = ExperienceParams(episodes_per_action=200, horizon=40)
# equal-width bins: the line world's points pile up at the wall (p = 0) and where B
# oscillates around p = 0.5, so quantile bins would be ~0.005 wide there
LINE = CellMapParams(bins=(20,), seen_feature=(-1,), spacing="uniform", categorical_dims=0,
                     start_window=20, max_iterations=4, min_points=5.0, min_reliability=0.8)
F, B = 0, 1


@pytest.fixture(scope="module")
def collect():
    return line_world_collector(CP.episodes_per_action, CP.horizon)


@pytest.fixture(scope="module")
def flipped(collect):
    exp = collect(jax.random.PRNGKey(0), 0.5)
    return exp, make_cell_builder(LINE)(exp)


def test_edges_are_quantiles_or_equal_widths_of_the_valid_points(flipped):
    exp, cm = flipped
    v = np.asarray(exp.x[..., 0])[np.asarray(exp.valid)].astype(np.float64)
    frac = np.linspace(0, 1, 21)[1:-1]
    np.testing.assert_allclose(np.asarray(cm.edges)[0], v.min() + frac * (v.max() - v.min()),
                               atol=1e-5)
    q = make_cell_builder(LINE.replace(spacing="quantile"))(exp)
    np.testing.assert_allclose(np.asarray(q.edges)[0], np.quantile(v, frac), atol=1e-5)


def test_line_world_with_swap_gives_hand_derived_states(flipped):
    _, cm = flipped
    assert_line_world_swap_map(cm, num_cell_states, classify_cells, cell_policy_action)
    assert int(cm.iterations) == 3          # the third iteration labels nothing


def test_policy_from_cell_map_reaches_goal(flipped):
    _, cm = flipped
    ep = ENV.default_params.replace(flip_below=0.5)
    ok, n = jax.jit(lambda k: rollout(
        ENV, ep, k, stateless(lambda o, _: cell_policy_action(cm, o)), 256, 60))(
        jax.random.PRNGKey(5))
    # only a start inside the one cell that straddles p = 0.5 (width ~0.05) may fail
    assert float(ok.mean()) >= 0.95


def test_line_world_without_swap_is_one_forward_state(collect):
    cm = make_cell_builder(LINE)(collect(jax.random.PRNGKey(2), 0.0))
    assert int(num_cell_states(cm)) == 1
    s = int(np.flatnonzero(np.asarray(cm.active))[0])
    assert int(cm.action[s]) == F and int(cm.transitions[s]) == 1
    xs = jnp.linspace(0.03, 0.97, 20, dtype=jnp.float32)[:, None]
    assert np.all(np.asarray(classify_cells(cm, xs)) == s)


def _reference(exp: Experience, p: CellMapParams, edges: np.ndarray):
    """Loop-based NumPy construction (float64) with the given bin edges."""
    x, valid, goal = (np.asarray(a) for a in (exp.x, exp.valid, exp.goal))
    n_act, n_ep, t1, d = x.shape
    n_pat = p.categorical_levels ** p.categorical_dims

    def cell(v):
        idx = 0
        for j, b in enumerate(p.bins):
            idx = idx * b + min(int(np.sum(v[j] > edges[j])), b - 1)
        pat = 0
        for j in range(p.categorical_dims):
            digit = int(np.clip(np.round(v[d - p.categorical_dims + j]
                                         * (p.categorical_levels - 1)),
                                0, p.categorical_levels - 1))
            pat += digit * p.categorical_levels ** j
        return idx * n_pat + pat

    cells = np.array([[[cell(x[a, n, t]) for t in range(t1)] for n in range(n_ep)]
                      for a in range(n_act)])
    n_cells = int(np.prod(p.bins)) * n_pat
    lab = np.full(n_cells, -1)
    ctime = np.zeros(n_cells)
    ctrans = np.zeros(n_cells, int)
    it = 0
    for it in range(p.max_iterations):   # noqa: B007
        stats = np.zeros((n_act, n_cells, 4))      # n_in, n_ok, sum time, sum transitions
        for a in range(n_act):
            for n in range(n_ep):
                for t in range(p.start_window):
                    c = cells[a, n, t]
                    if not valid[a, n, t] or lab[c] >= 0:
                        continue
                    stats[a, c, 0] += 1
                    for s in range(t, t1 - 1):
                        if goal[a, n, s]:
                            stats[a, c, 1:] += (1, s - t + 1, 1)
                            break
                        nxt = cells[a, n, s + 1]
                        if valid[a, n, s + 1] and lab[nxt] >= 0:
                            stats[a, c, 1:] += (1, s + 1 - t + ctime[nxt], 1 + ctrans[nxt])
                            break
        new = False
        old = lab.copy()
        for c in range(n_cells):
            if old[c] >= 0:
                continue
            best, best_v = -1, -np.inf
            for a in range(n_act):
                n_in, n_ok, s_tm, s_tr = stats[a, c]
                rel = n_ok / max(n_in, 1)
                if n_in >= p.min_points and rel >= p.min_reliability:
                    v = rel * p.discount ** (s_tm / max(n_ok, 1))
                    if v > best_v:
                        best, best_v = a, v
            if best >= 0:
                n_in, n_ok, s_tm, s_tr = stats[best, c]
                lab[c] = it * n_act + best
                ctime[c] = s_tm / n_ok
                ctrans[c] = int(np.round(s_tr / n_ok))
                new = True
        if not new:
            break
    return lab, ctime, np.where(lab >= 0, ctrans, 0), it + 1


def _random_experience(key, n_act=3, n_ep=30, t1=13):
    """Two continuous features and one categorical (0, 0.5, 1), random episode lengths and
    sparse goals, so that chains of several iterations form."""
    k1, k2, k3, k4 = jax.random.split(key, 4)
    cont = jax.random.uniform(k1, (n_act, n_ep, t1, 2))
    cat = jax.random.randint(k2, (n_act, n_ep, t1, 1), 0, 3) / 2.0
    x = jnp.concatenate([cont, cat], axis=-1).astype(jnp.float32)
    length = jax.random.randint(k3, (n_act, n_ep, 1), 4, t1 + 1)
    valid = jnp.arange(t1)[None, None] < length
    goal = (jax.random.uniform(k4, (n_act, n_ep, t1 - 1)) < 0.08) & valid[..., 1:]
    return Experience(x=x, valid=valid, goal=goal)


def test_labelling_matches_numpy_reference():
    exp = _random_experience(jax.random.PRNGKey(3))
    p = CellMapParams(bins=(3, 2), seen_feature=(-1, 2), categorical_dims=1, start_window=8,
                      max_iterations=6, min_points=2.0, min_reliability=0.3, discount=0.9)
    cm = make_cell_builder(p)(exp)
    lab, ctime, ctrans, iters = _reference(exp, p, np.asarray(cm.edges, np.float64))
    assert int(num_cell_states(cm)) >= 3 and int(cm.iterations) >= 2    # chains formed
    np.testing.assert_array_equal(np.asarray(cm.cell_state), lab)
    np.testing.assert_allclose(np.asarray(cm.cell_time), np.where(lab >= 0, ctime, 0.0),
                               rtol=1e-5)
    np.testing.assert_array_equal(np.asarray(cm.cell_transitions), ctrans)
    assert int(cm.iterations) == iters
    # the remainder's primitive per pattern: the most frequent among that pattern's cells
    acts = np.where(lab >= 0, lab % 3, -1)
    for pat in range(3):
        a = acts[pat::3]
        counts = np.bincount(a[a >= 0], minlength=3)
        assert int(cm.fallback[pat]) == int(np.argmax(counts))
    # a state's transitions: the fewest of its cells
    for s in np.flatnonzero(np.asarray(cm.active)):
        assert int(cm.transitions[s]) == int(ctrans[lab == s].min())
    # edges of the categorical-gated feature come from the points whose pattern is "seen"
    x, v = np.asarray(exp.x), np.asarray(exp.valid)
    seen = v & (x[..., 2] == 0.5)
    np.testing.assert_allclose(np.asarray(cm.edges)[1, 0], np.quantile(x[..., 1][seen], 0.5),
                               atol=1e-5)


def test_cell_index_reads_bins_and_pattern():
    exp = _random_experience(jax.random.PRNGKey(4))
    p = CellMapParams(bins=(3, 2), seen_feature=(-1, -1), categorical_dims=1, start_window=8)
    cm = make_cell_builder(p)(exp)
    e = np.asarray(cm.edges)
    x = jnp.array([[e[0, 0] - 0.01, e[1, 0] + 0.01, 1.0],     # bins (0, 1), pattern 2
                   [e[0, 1] + 0.01, e[1, 0] - 0.01, 0.0]],    # bins (2, 0), pattern 0
                  jnp.float32)
    np.testing.assert_array_equal(np.asarray(cell_index(cm, x)), [(0 * 2 + 1) * 3 + 2,
                                                                  (2 * 2 + 0) * 3 + 0])


def test_deterministic_and_batched_equals_looped(collect, flipped):
    exp, cm = flipped
    again = make_cell_builder(LINE)(exp)
    for a, b in zip(jax.tree_util.tree_leaves(cm), jax.tree_util.tree_leaves(again),
                    strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    exps = [exp, collect(jax.random.PRNGKey(7), 0.5)]
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *exps)
    rel = jnp.array([0.8, 0.6], jnp.float32)           # a traced threshold, vmapped too
    batched = jax.jit(jax.vmap(lambda e, r: build_cell_map(e, LINE.replace(
        min_reliability=r))))(stacked, rel)
    for i in range(2):
        single = make_cell_builder(LINE.replace(min_reliability=float(rel[i])))(exps[i])
        for name in ("cell_state", "cell_transitions", "fallback", "active", "transitions",
                     "iterations"):
            np.testing.assert_array_equal(np.asarray(getattr(single, name)),
                                          np.asarray(getattr(batched, name))[i], err_msg=name)
        np.testing.assert_allclose(np.asarray(single.cell_time),
                                   np.asarray(batched.cell_time)[i], rtol=1e-6)


def test_bad_settings_raise_clear_errors(flipped):
    exp, _ = flipped
    with pytest.raises(ParamError, match="min_reliability"):
        make_cell_builder(LINE.replace(min_reliability=1.5))
    with pytest.raises(ParamError, match="bins"):
        make_cell_builder(LINE.replace(bins=(0,)))
    with pytest.raises(ParamError, match="one entry per continuous feature"):
        make_cell_builder(LINE.replace(bins=(4, 4)))
    with pytest.raises(ParamError, match="continuous features"):
        make_cell_builder(LINE.replace(bins=(4, 4), seen_feature=(-1, -1)))(exp)
    with pytest.raises(ParamError, match="categorical_dims"):
        make_cell_builder(LINE.replace(categorical_dims=1))(exp)
    with pytest.raises(ParamError, match="start_window"):
        make_cell_builder(LINE.replace(start_window=41))(exp)
    with pytest.raises(ParamError, match="seen_feature"):
        make_cell_builder(LINE.replace(seen_feature=(3,)))(exp)


def test_fig5_uses_cells_and_checks_its_bins():
    from vbl.engine.registry import get

    exp = get("fig5_action_based")
    cfg = exp.default_config
    assert cfg.collect.difficulty_hi == pytest.approx(0.3)
    assert len(cfg.cells.bins) == cfg.features.dim - cfg.cells.categorical_dims
    with pytest.raises(ParamError, match="cells.bins"):
        exp.make_program(cfg.replace(cells=cfg.cells.replace(bins=(4, 5, 3), seen_feature=(
            5, 5, 6))))
