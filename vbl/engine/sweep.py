"""Sweep plans: the grid of sweep points x seeds, grouped by static values.

A *point* is one combination of sweep values (``{path: value}``). Points that share their
static values form a *group*: one ``make_program`` call and one compilation. Inside a group
the learners are ``(point, seed)`` pairs in point-major order, learner ``i`` = point
``i // seeds``, seed ``i % seeds``.

A *shard* ``i/N`` of a plan holds the ``i``-th of ``N`` contiguous parts of the plan's
learners in global order (learner ``point * seeds + seed``); its groups keep their step
offsets and run only their learners in the shard (:attr:`Group.members`), with the keys
and configs the unsharded run gives them.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from vbl.engine.config import INT32, apply_overrides, set_value, stack_traced
from vbl.engine.experiment import Experiment, Program
from vbl.params import ParamError, get_path, static_paths

__all__ = ["Group", "SweepPlan", "Shard", "make_plan", "learner_keys", "program_for",
           "parse_shard", "MAX_POINTS", "MAX_SEED"]

MAX_POINTS = 1_000_000  #: most sweep points (the product of the sweep's value counts)
MAX_SEED = INT32[1]  #: largest --seed and --seeds (keys are folded from int32 seeds)

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


@dataclass(frozen=True)
class Shard:
    """Part ``index`` (1-based) of ``count`` of a plan's learners."""

    index: int
    count: int

    def __post_init__(self) -> None:
        ok = all(isinstance(v, int) and not isinstance(v, bool) for v in (self.index, self.count))
        if not ok or not 1 <= self.index <= self.count:
            raise ParamError(f"--shard {self.index}/{self.count}: the part I of I/N must be in "
                             f"1..N")

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"

    def learner_range(self, num_learners: int) -> tuple[int, int]:
        """``[lo, hi)`` of the global learner indices in this part (sizes differ by at
        most one)."""
        return ((self.index - 1) * num_learners // self.count,
                self.index * num_learners // self.count)


def parse_shard(text: Any) -> Shard:
    """``"i/N"`` (1 <= i <= N) -> :class:`Shard`; ParamError otherwise."""
    try:
        i, n = (int(x) for x in str(text).split("/"))
    except ValueError:
        raise ParamError(f"--shard takes I/N (part I of N, 1 <= I <= N), got {text!r}") from None
    return Shard(i, n)


@dataclass
class Group:
    """Points sharing static values: one program, one compilation.

    :attr:`point_configs` holds one validated config per point and :attr:`configs` stacks
    their traced leaves for the learners that run (``[num_learners, ...]`` NumPy arrays,
    point-major as :attr:`members`); both are built on first
    use, so that a plan can be checked (memory, from :attr:`first_config`) before a large
    sweep is validated point by point or anything large is allocated. ``point_ids``
    indexes ``points``, the plan's points. ``members`` lists the group's learners that
    run, as ``(point, first seed, end seed)`` in the group's order: every seed of every
    point, or a shard's part.
    """

    index: int
    static_values: dict[str, Any]
    point_ids: list[int]
    base_config: Any
    program: Program
    points: list[dict[str, Any]]
    step_offset: int
    seeds: int
    members: list[tuple[int, int, int]]

    @property
    def first_config(self) -> Any:
        """The validated config of the group's first point."""
        if "point_configs" in self.__dict__:
            return self.point_configs[0]
        return apply_overrides(self.base_config, self.points[self.point_ids[0]])

    @functools.cached_property
    def point_configs(self) -> list[Any]:
        return [apply_overrides(self.base_config, self.points[i]) for i in self.point_ids]

    @property
    def num_chunks(self) -> int:
        return self.program.num_chunks

    @property
    def num_learners(self) -> int:
        return sum(hi - lo for _, lo, hi in self.members)

    @functools.cached_property
    def learner_index(self) -> np.ndarray:
        """Positions of the members' learners among all ``points x seeds`` of the group."""
        pos = {p: j for j, p in enumerate(self.point_ids)}
        return np.concatenate([np.arange(pos[p] * self.seeds + lo, pos[p] * self.seeds + hi)
                               for p, lo, hi in self.members] or [np.zeros(0, np.int64)])

    def select(self, per_seed: np.ndarray) -> np.ndarray:
        """The members' rows of ``per_seed`` (``[seeds, ...]``, e.g. the plan's keys)."""
        return np.tile(per_seed, (len(self.point_ids),) + (1,) * (per_seed.ndim - 1))[
            self.learner_index]

    @functools.cached_property
    def configs(self) -> Any:
        stacked = stack_traced(self.point_configs, self.seeds)
        if self.num_learners == len(self.point_ids) * self.seeds:
            return stacked
        return jax.tree.map(lambda x: x[self.learner_index], stacked)


@dataclass
class SweepPlan:
    config: Any  # resolved base config
    sweep: dict[str, list[Any]]
    points: list[dict[str, Any]]
    seeds: int
    base_seed: int
    groups: list[Group]
    shard: Shard | None = None

    @property
    def total_steps(self) -> int:
        """Steps (chunks) of the whole plan; a shard's groups keep their step offsets."""
        return sum(g.num_chunks for g in self.groups)

    @property
    def num_learners(self) -> int:
        """Learners that run (a shard's part of ``points x seeds``)."""
        return sum(g.num_learners for g in self.groups)

    @functools.cached_property
    def _keys(self) -> tuple[np.ndarray, np.ndarray]:
        return learner_keys(self.base_seed, self.seeds)

    @property
    def init_keys(self) -> np.ndarray:
        """uint32[seeds, 2] (built on first use)."""
        return self._keys[0]

    @property
    def final_keys(self) -> np.ndarray:
        return self._keys[1]

    def validate(self) -> None:
        """Build (hence validate) every point's config; ParamError names the first bad one."""
        for g in self.groups:
            g.point_configs  # noqa: B018 - built and cached


def check_counts(seeds: Any, base_seed: Any) -> None:
    """ParamError unless ``1 <= seeds <= MAX_SEED`` and ``0 <= base_seed <= MAX_SEED``."""
    if isinstance(seeds, bool) or not isinstance(seeds, int) or not 1 <= seeds <= MAX_SEED:
        raise ParamError(f"seeds must be an int in [1, {MAX_SEED}], got {seeds!r}")
    if isinstance(base_seed, bool) or not isinstance(base_seed, int) or not (
            0 <= base_seed <= MAX_SEED):
        raise ParamError(f"the base seed must be an int in [0, {MAX_SEED}], got {base_seed!r}")


def _members(point_ids: list[int], seeds: int, lo: int, hi: int) -> list[tuple[int, int, int]]:
    """``(point, first seed, end seed)`` of the learners ``[lo, hi)`` (global order) among
    ``point_ids``'s."""
    out = []
    for p in point_ids:
        a, b = max(lo, p * seeds), min(hi, (p + 1) * seeds)
        if a < b:
            out.append((p, a - p * seeds, b - p * seeds))
    return out


def _zipped_count(sweep: dict[str, list[Any]]) -> int:
    """The points of a zipped sweep: its paths' common number of values."""
    counts = {len(v) for v in sweep.values()}
    if len(counts) > 1:
        raise ParamError(f"a zipped sweep gives every path one value per point; the paths "
                         f"have {sorted(counts)} values")
    return counts.pop() if counts else 1


def make_plan(experiment: Experiment, config: Any, sweep: Mapping[str, Sequence[Any]],
              seeds: int, base_seed: int = 0, shard: Shard | None = None,
              zipped: bool = False) -> SweepPlan:
    """Validate every sweep value and build the groups (calls ``make_program`` per group).
    Each point's config (validated whole) and the per-learner arrays (keys, stacked
    configs) are built on first use: :meth:`SweepPlan.validate` builds the configs. With
    ``shard``, only its part of the learners runs (ParamError when a part would be
    empty). ``zipped``: the points are the sweep's values side by side (point ``i`` takes
    the ``i``-th value of every path; the same count for every path), not their product."""
    check_counts(seeds, base_seed)
    sweep = {p: list(v) for p, v in sweep.items()}
    for path, values in sweep.items():
        if not values:
            raise ParamError(f"sweep of {path!r} has no values")
        for v in values:
            set_value(config, path, v)  # type/range check with a clear message
    npoints = _zipped_count(sweep) if zipped else math.prod(len(v) for v in sweep.values())
    if npoints > MAX_POINTS:
        raise ParamError(f"the sweep has {npoints:,} points (the product of its value "
                         f"counts); at most {MAX_POINTS:,}")
    statics = set(static_paths(config))
    paths = list(sweep)
    combos = zip(*(sweep[p] for p in paths), strict=True) if zipped else \
        itertools.product(*(sweep[p] for p in paths))
    points = [dict(zip(paths, combo, strict=True)) for combo in combos]
    if not points:
        points = [{}]
    by_static: dict[tuple, list[int]] = {}
    for i, pt in enumerate(points):
        key = tuple((p, repr(v)) for p, v in pt.items() if p in statics)
        by_static.setdefault(key, []).append(i)
    total = len(points) * seeds
    if shard is not None and shard.count > total:
        raise ParamError(f"--shard {shard}: at most {total} parts (this run has {len(points)} "
                         f"sweep point{'s' * (len(points) != 1)} x {seeds} seed"
                         f"{'s' * (seeds != 1)} = {total} learners)")
    lo, hi = shard.learner_range(total) if shard is not None else (0, total)
    groups, offset = [], 0
    for gi, ids in enumerate(by_static.values()):
        static_values = {p: v for p, v in points[ids[0]].items() if p in statics}
        base = apply_overrides(config, static_values)
        program = program_for(experiment, base)
        groups.append(Group(gi, static_values, ids, base, program, points, offset, seeds,
                            _members(ids, seeds, lo, hi)))
        offset += program.num_chunks
    return SweepPlan(config, sweep, points, seeds, base_seed, groups, shard)
