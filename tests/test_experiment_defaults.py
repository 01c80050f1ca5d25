"""Every registered experiment plans at its defaults and at ``--quick``: the configs
validate and every group's program builds (``make_program`` runs its own checks; ``run=``
experiments: the config validates), so ``vbl run NAME`` and ``vbl reproduce`` never stop on
a default that the checks refuse."""

from __future__ import annotations

import pytest

from vbl.engine import registry
from vbl.engine.jax_setup import engine_precision
from vbl.engine.runner import resolve
from vbl.engine.sweep import make_plan

NAMES = sorted(registry.discover())


@pytest.mark.parametrize("quick", [False, True], ids=["full", "quick"])
@pytest.mark.parametrize("name", NAMES)
def test_experiment_plans_at_its_defaults(name, quick):
    exp = registry.get(name)
    with engine_precision():
        config, sweep, seeds, _ = resolve(exp, quick=quick)
        if exp.make_program is None:  # a run= experiment: validated config only
            return
        plan = make_plan(exp, config, sweep, seeds)
    assert plan.groups and all(g.num_learners >= 1 for g in plan.groups)


MAX_DEPTH = 4  #: names per parameter path at most (e.g. env.world.field.length)


@pytest.mark.parametrize("name", NAMES)
def test_parameter_paths_are_shallow_and_do_not_stutter(name):
    """A user types these paths in --set and --sweep: at most MAX_DEPTH names, and no name
    right after itself (as in a former agent.agent.learning_rate)."""
    from vbl.engine.config import config_to_dict

    for path in config_to_dict(registry.get(name).default_config):
        names = path.split(".")
        assert len(names) <= MAX_DEPTH, path
        assert all(a != b for a, b in zip(names, names[1:], strict=False)), path


def test_table2_quick_is_the_full_run_shortened():
    """Table 2's --quick compiles the full run's programs (every static parameter equal but
    the chunk count, the same seeds) and scales each schedule by the chunk ratio, so it is
    the full run stopped early, with its exploration and step-size decay completed."""
    from vbl.engine.config import config_to_dict, static_paths

    exp = registry.get("table2_shoot_pass")
    with engine_precision():
        full, _, full_seeds, _ = resolve(exp)
        quick, _, quick_seeds, _ = resolve(exp, quick=True)
    f, q = config_to_dict(full), config_to_dict(quick)
    ratio = q["train.num_chunks"] / f["train.num_chunks"]
    assert ratio < 1 and quick_seeds == full_seeds
    assert {p: q[p] for p in static_paths(full) if p != "train.num_chunks"} == \
        {p: f[p] for p in static_paths(full) if p != "train.num_chunks"}
    for p in ("agent.exploration.transition_steps", "train.lr_scale.transition_begin",
              "train.lr_scale.transition_steps"):
        assert q[p] == pytest.approx(ratio * f[p])
    changed = {p for p in f if f[p] != q[p]}
    assert changed == {"train.num_chunks", "agent.exploration.transition_steps",
                       "train.lr_scale.transition_begin", "train.lr_scale.transition_steps"}
