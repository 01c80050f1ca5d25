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
