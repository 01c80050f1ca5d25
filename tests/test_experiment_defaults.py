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
