"""Sweep plans (vbl/engine/sweep.py) without running anything: shards' parts of the
learners, the learners of a group, the keys each seed gets, and the counts accepted.

Truths: hand-counted learner ranges and jax.random's documented key derivation."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from vbl.engine.sweep import MAX_SEED, Group, Shard, learner_keys, parse_shard
from vbl.params import ParamError


@pytest.mark.parametrize("total", [1, 7, 10, 12])
def test_shards_are_contiguous_parts_differing_by_at_most_one_learner(total):
    for count in range(1, total + 1):
        parts = [Shard(i, count).learner_range(total) for i in range(1, count + 1)]
        assert parts[0][0] == 0 and parts[-1][1] == total
        assert all(a[1] == b[0] for a, b in zip(parts, parts[1:], strict=False))
        sizes = [hi - lo for lo, hi in parts]
        assert min(sizes) >= 1 and max(sizes) - min(sizes) <= 1
    assert [Shard(i, 3).learner_range(7) for i in (1, 2, 3)] == [(0, 2), (2, 4), (4, 7)]


def test_a_shard_is_part_1_to_n_of_n():
    assert parse_shard("3/3") == Shard(3, 3) and str(parse_shard(" 1/2")) == "1/2"
    for text in ("0/3", "4/3", "a/b", "1/2/3", "2"):
        with pytest.raises(ParamError):
            parse_shard(text)
    with pytest.raises(ParamError):
        Shard(True, 2)


def _group(point_ids, seeds, lo, hi):
    from vbl.engine.sweep import _members

    members = _members(point_ids, seeds, lo, hi)
    return Group(0, {}, point_ids, None, None, [], 0, seeds, members)


def test_a_shards_members_are_its_learners_point_by_point():
    g = _group([0, 1, 2], 4, 3, 9)  # learners 3..8: point 0 seed 3, point 1, point 2 seed 0
    assert g.members == [(0, 3, 4), (1, 0, 4), (2, 0, 1)] and g.num_learners == 6
    np.testing.assert_array_equal(g.learner_index, np.arange(3, 9))
    # a group of the plan's points 1 and 3 (another static value between them)
    g = _group([1, 3], 2, 0, 8)
    assert g.members == [(1, 0, 2), (3, 0, 2)]
    np.testing.assert_array_equal(g.learner_index, [0, 1, 2, 3])


def test_every_point_of_a_group_gets_the_same_seeds_keys():
    keys = np.array([[10, 11], [20, 21], [30, 31]], np.uint32)  # (seeds, 2)
    g = _group([0, 1], 3, 0, 6)
    np.testing.assert_array_equal(g.select(keys), np.concatenate([keys, keys]))
    g = _group([0, 1], 3, 2, 5)  # point 0 seed 2, point 1 seeds 0 and 1
    np.testing.assert_array_equal(g.select(keys), keys[[2, 0, 1]])


def test_learner_keys_depend_on_the_base_seed_and_the_seed_index_only():
    k_train, k_final = jax.random.split(jax.random.PRNGKey(5))
    init, final = learner_keys(5, 3)
    for s in range(3):
        np.testing.assert_array_equal(init[s], jax.random.fold_in(k_train, s))
        np.testing.assert_array_equal(final[s], jax.random.fold_in(k_final, s))
    np.testing.assert_array_equal(learner_keys(5, 2)[0], init[:2])


@pytest.mark.parametrize("seeds, base_seed", [(0, 0), (MAX_SEED + 1, 0), (True, 0),
                                              (2, -1), (2, MAX_SEED + 1), (2, 1.0)])
def test_seed_counts_out_of_range_are_refused(seeds, base_seed):
    from vbl.engine.sweep import check_counts

    check_counts(1, 0)
    check_counts(MAX_SEED, MAX_SEED)
    with pytest.raises(ParamError):
        check_counts(seeds, base_seed)


def test_a_zipped_sweep_needs_one_count_for_every_path():
    from vbl.engine.sweep import _zipped_count

    assert _zipped_count({}) == 1 and _zipped_count({"a": [1, 2], "b": [3, 4]}) == 2
    with pytest.raises(ParamError, match=r"\[1, 2\] values"):
        _zipped_count({"a": [1, 2], "b": [3]})


def test_as_many_shards_as_learners_run_one_learner_each_and_more_are_refused(tmp_path):
    """2 sweep points x 2 seeds = 4 learners: --shard i/4 runs learner i - 1 alone; 5
    parts would leave one empty."""
    from tests.engine_helpers import toy_experiment
    from vbl.engine.sweep import make_plan

    gen = toy_experiment(tmp_path)
    toy = next(gen)
    try:
        sweep = {"agent.epsilon": [0.1, 0.2]}
        for i in range(1, 5):
            plan = make_plan(toy, toy.default_config, sweep, 2, shard=Shard(i, 4))
            learners = [ix for g in plan.groups for ix in g.learner_index.tolist()]
            assert learners == [i - 1]
        with pytest.raises(ParamError, match="at most 4 parts"):
            make_plan(toy, toy.default_config, sweep, 2, shard=Shard(5, 5))
    finally:
        next(gen, None)
