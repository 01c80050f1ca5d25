"""Sweep plans: the grid of sweep points x seeds, grouped by static values.

A *point* is one combination of sweep values (``{path: value}``). Points that share their
static values form a *group*: one ``make_program`` call and one compilation. Inside a group
the learners are ``(point, seed)`` pairs in point-major order, learner ``i`` = point
``i // seeds``, seed ``i % seeds``.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from vbl.engine.config import apply_overrides, stack_traced
from vbl.engine.experiment import Experiment, Program
from vbl.params import ParamError, get_path, replace_path, static_paths

__all__ = ["Group", "SweepPlan", "make_plan", "learner_keys", "program_for"]

# (make_program, static values) -> Program: repeated runs in one process (tests, notebooks,
# `vbl reproduce`) reuse the same functions, hence jax's compilation cache.
_PROGRAMS: dict[tuple, Program] = {}


def program_for(experiment: Experiment, config: Any) -> Program:
    """``experiment.make_program(config)``, cached on the static values of ``config``."""
    key = (experiment.make_program,
           tuple((p, repr(get_path(config, p))) for p in static_paths(config)))
    prog = _PROGRAMS.get(key)
    if prog is None:
        prog = experiment.make_program(config)
        if not isinstance(prog, Program):
            raise TypeError(f"{experiment.name}: make_program must return a Program, got "
                            f"{type(prog).__name__}")
        _PROGRAMS[key] = prog
    return prog


def learner_keys(base_seed: int, seeds: int) -> tuple[np.ndarray, np.ndarray]:
    """``(init_keys, final_keys)``, each ``uint32[seeds, 2]``.

    ``init_key[s] = fold_in(split(PRNGKey(base_seed))[0], s)`` and
    ``final_key[s] = fold_in(split(PRNGKey(base_seed))[1], s)``: they depend only on the base
    seed and the seed index, never on the sweep point, device or process count.
    """
    base = jax.random.PRNGKey(base_seed)
    k_train, k_final = jax.random.split(base)
    idx = np.arange(seeds, dtype=np.uint32)
    fold = jax.vmap(jax.random.fold_in, in_axes=(None, 0))
    return (np.asarray(fold(k_train, idx), dtype=np.uint32),
            np.asarray(fold(k_final, idx), dtype=np.uint32))


@dataclass
class Group:
    """Points sharing static values: one program, one compilation.

    ``configs`` holds the stacked traced leaves (``[points * seeds, ...]`` NumPy arrays);
    ``point_ids`` indexes :attr:`SweepPlan.points`.
    """

    index: int
    static_values: dict[str, Any]
    point_ids: list[int]
    base_config: Any
    program: Program
    configs: Any
    step_offset: int
    seeds: int

    @property
    def num_chunks(self) -> int:
        return self.program.num_chunks

    @property
    def num_learners(self) -> int:
        return len(self.point_ids) * self.seeds


@dataclass
class SweepPlan:
    config: Any  # resolved base config
    sweep: dict[str, list[Any]]
    points: list[dict[str, Any]]
    seeds: int
    base_seed: int
    groups: list[Group]
    init_keys: np.ndarray  # uint32[seeds, 2]
    final_keys: np.ndarray

    @property
    def total_steps(self) -> int:
        return sum(g.num_chunks for g in self.groups)

    @property
    def num_learners(self) -> int:
        return len(self.points) * self.seeds


def make_plan(experiment: Experiment, config: Any, sweep: Mapping[str, Sequence[Any]],
              seeds: int, base_seed: int = 0) -> SweepPlan:
    """Validate every sweep value and build the groups (calls ``make_program`` per group)."""
    if not isinstance(seeds, int) or seeds < 1:
        raise ParamError(f"seeds must be an int >= 1, got {seeds!r}")
    if not isinstance(base_seed, int) or base_seed < 0:
        raise ParamError(f"base seed must be an int >= 0, got {base_seed!r}")
    sweep = {p: list(v) for p, v in sweep.items()}
    for path, values in sweep.items():
        if not values:
            raise ParamError(f"sweep of {path!r} has no values")
        for v in values:
            replace_path(config, path, v)  # type/range check with a clear message
    statics = set(static_paths(config))
    paths = list(sweep)
    points = [dict(zip(paths, combo, strict=True))
              for combo in itertools.product(*(sweep[p] for p in paths))]
    if not points:
        points = [{}]
    by_static: dict[tuple, list[int]] = {}
    for i, pt in enumerate(points):
        key = tuple((p, repr(v)) for p, v in pt.items() if p in statics)
        by_static.setdefault(key, []).append(i)
    init_keys, final_keys = learner_keys(base_seed, seeds)
    groups, offset = [], 0
    for gi, ids in enumerate(by_static.values()):
        static_values = {p: v for p, v in points[ids[0]].items() if p in statics}
        base = apply_overrides(config, static_values)
        cfgs = [apply_overrides(config, points[i]) for i in ids]
        program = program_for(experiment, base)
        groups.append(Group(gi, static_values, ids, base, program,
                            stack_traced(cfgs, seeds), offset, seeds))
        offset += program.num_chunks
    return SweepPlan(config, sweep, points, seeds, base_seed, groups, init_keys, final_keys)
