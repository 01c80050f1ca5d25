"""The experiment contract: what an experiment script gives the engine.

An experiment is a *program* in the purejaxrl style: one learner's whole run is a pure
function of ``(key, config)``, cut into ``num_chunks`` chunks so that the engine can show
progress, write metrics and checkpoint between them. The engine ``vmap``s the program over
learners (sweep values x seeds), ``jit``s it and shards the learner axis over devices.

See ``docs/engine.md`` for a complete example.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax

from vbl.params import ParamError, get_path

__all__ = ["Program", "finish", "Experiment", "RunResult", "ReportSection", "RunContext",
           "PaperRow"]

Config = Any  # a flax.struct dataclass declared with vbl.params.param/section
Carry = Any  # any pytree of arrays (one learner's state)
Metrics = dict[str, jax.Array]


@dataclass(frozen=True)
class Program:
    """One learner's whole run as pure functions; the engine vmaps them over learners.

    Attributes:
      init: ``(key, config) -> carry``. ``key`` is a raw ``uint32[2]`` PRNG key that depends
        only on ``(base seed, seed index)``; ``config`` holds the *traced* fields of one
        learner (float fields as ``float32`` scalars, int fields as ``int32``, bools as
        ``bool``), static fields as plain Python values.
      step: ``(carry, config) -> (carry, metrics)``: run one chunk. ``metrics`` maps names to
        float/int scalars or small fixed-shape arrays (per learner). ``episodes`` (episodes
        finished in the chunk) is the progress bar's episodes/s and the plots' x axis. Name
        success rates by what they measure: ``train_success`` (training episodes, with
        exploration), ``eval_success`` / ``greedy_success`` (an evaluation of the learned
        policy).
      num_chunks: number of ``step`` calls in one run (>= 1).
      final: optional ``(carry, config, key) -> metrics`` evaluated once after the last chunk
        (e.g. greedy evaluation on fresh starts); ``key`` is independent of the training keys.
      begin_final: optional ``(carry, config, key) -> carry`` for a program whose final
        evaluation runs through its own ``step`` (so the evaluation is compiled once): after
        the last chunk the engine calls it with the final ``key``, then ``step``
        ``final_steps`` times (their metrics are dropped), then ``final`` on that carry
        (:func:`finish`). The checkpoint keeps the carry of the last training chunk.
      final_steps: ``step`` calls after ``begin_final`` (>= 1 with it, 0 without).
      progress_metric: the per-chunk metric the progress bar shows beside the rate (e.g.
        ``"eval_success"``); None: none.
    """

    init: Callable[[jax.Array, Config], Carry]
    step: Callable[[Carry, Config], tuple[Carry, Metrics]]
    num_chunks: int
    final: Callable[[Carry, Config, jax.Array], Metrics] | None = None
    progress_metric: str | None = None
    begin_final: Callable[[Carry, Config, jax.Array], Carry] | None = None
    final_steps: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.num_chunks, int) or self.num_chunks < 1:
            raise ValueError(f"Program.num_chunks must be an int >= 1, got {self.num_chunks!r}")
        if self.begin_final is None:
            if self.final_steps != 0:
                raise ValueError(f"Program.final_steps={self.final_steps!r} needs begin_final "
                                 "(without it, final_steps is 0)")
        elif self.final is None or not isinstance(self.final_steps, int) \
                or self.final_steps < 1:
            raise ValueError("Program.begin_final needs final and an int final_steps >= 1, "
                             f"got final={self.final!r}, final_steps={self.final_steps!r}")


def finish(prog: Program, carry: Carry, config: Config, key: jax.Array) -> Metrics:
    """``prog.final``'s metrics of a trained ``carry`` in one traced call (for a program run
    inside another): ``begin_final``, ``final_steps`` x ``step`` in a ``fori_loop``, then
    ``final``; ``final`` alone for a program without ``begin_final``."""
    if prog.begin_final is not None:
        carry = jax.lax.fori_loop(0, prog.final_steps, lambda _, c: prog.step(c, config)[0],
                                  prog.begin_final(carry, config, key))
    return prog.final(carry, config, key)


@dataclass(frozen=True)
class ReportSection:
    """One experiment's part of ``report.md`` (written by ``vbl reproduce``).

    ``markdown`` compares our numbers with the paper's; ``figures`` are PNG paths
    (absolute, or relative to the run folder) that the report links.
    """

    markdown: str
    figures: tuple[str | Path, ...] = ()


@dataclass(frozen=True)
class PaperRow:
    """One line of ``vbl report``'s results table: a paper number beside vbl's.

    ``result``: what is compared (e.g. "Table 2, shooting, CVA state, %"); ``paper``: the
    paper's number, or its claim when it gives none; ``ours``: vbl's number with its 95 %
    interval over seeds (e.g. "16.8 ± 2.7"; see :func:`vbl.engine.report.stat_cell`).
    """

    result: str
    paper: str
    ours: str


@dataclass
class RunResult:
    """What a finished run hands to ``Experiment.report``.

    Attributes:
      experiment: the experiment's name.
      out_dir: the run folder.
      config: the resolved base config (before sweep values).
      sweep: ``{path: [values]}`` of the sweep (empty when none).
      points: one dict ``{path: value}`` per sweep point (a single ``{}`` without a sweep).
      seeds: seeds per sweep point.
      curves: ``{metric: array[points, chunks, seeds, ...]}`` per-chunk metrics.
      final: ``{metric: array[points, seeds, ...]}`` from ``Program.final`` (may be empty).
      summary: the content of ``summary.json``.
      figures: PNG paths written by the engine.
      extra: anything an experiment's ``run`` escape hatch returns.
    """

    experiment: str
    out_dir: Path
    config: Config
    sweep: dict[str, list[Any]]
    points: list[dict[str, Any]]
    seeds: int
    curves: dict[str, Any]
    final: dict[str, Any]
    summary: dict[str, Any]
    figures: list[Path] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class RunContext:
    """Given to ``Experiment.run`` (the escape hatch for jobs that are not chunked programs).

    Attributes:
      config: the resolved, validated config.
      seeds: number of seeds asked for; ``base_seed``: the run's base seed.
      out_dir: the run folder (already created; config.json already written).
      quick: True under ``--quick``.
      log: ``log(step, metrics_dict)`` appends a JSON line to ``metrics.jsonl``.
      quiet: True when progress output is off.
    """

    config: Config
    seeds: int
    base_seed: int
    out_dir: Path
    quick: bool
    log: Callable[[int, Mapping[str, Any]], None]
    quiet: bool


@dataclass(frozen=True)
class Experiment:
    """A registered experiment: a config, a program factory, and how to report it.

    Attributes:
      name: CLI name (``vbl run NAME``); letters, digits, ``_`` and ``-``.
      description: one line for ``vbl list``.
      default_config: a ``flax.struct`` dataclass instance built from ``vbl.params`` fields,
        usually with sections (``env``, ``agent``, ``train``).
      make_program: ``config -> Program``; may read static fields of ``config`` (shapes, code
        paths, ``num_chunks``); must not depend on traced values (those arrive in ``init``/
        ``step``). Called once per combination of static values.
      run: escape hatch for jobs that are not chunked programs: ``run(ctx: RunContext) ->
        dict`` (JSON-able summary); the engine still writes the run folder. Exactly one of
        ``make_program`` and ``run`` must be given.
      quick: ``{dotted.path: value}`` overrides applied by ``--quick`` (before ``--set``); a
        path of the default ``sweep`` that it fixes leaves the sweep, as with ``--set``.
      seeds: default number of seeds; ``quick_seeds``: the number under ``--quick``.
      paper_result: True if ``vbl reproduce`` should run it.
      in_quick_reproduce: False leaves a paper result out of ``vbl reproduce --quick``
        (the full run keeps it): for a result whose quick scale trains too little to show
        anything, such as a deep-RL comparator (``vbl run NAME --quick`` still runs it).
      paper: the paper's numbers (free-form, for ``report``).
      report: ``RunResult -> ReportSection`` for ``vbl reproduce``.
      sweep: default sweep ``{path: [values]}`` (e.g. the table rows a paper result needs);
        ``--sweep`` on the command line replaces it for the paths it names.
      group: experiments with the same group run one after the other in one worker of
        ``vbl reproduce --jobs N`` (in registry order), so the later ones find the programs
        the first one compiled in the persistent compilation cache (experiments that
        build the same programs).
      percent: show success rates (:func:`vbl.engine.plots.is_rate`) in % in the terminal
        table, the default report and the curve plots, where the paper gives this result
        in % (Table 2); the data (``metrics.jsonl``, ``summary.json``, exports) keep
        fractions. One unit per metric: an experiment's own ``report`` follows it too.
      headline: metric names ``vbl run`` prints per sweep point after a run (mean and 95 %
        interval; a ``final`` metric, else the last chunk's); default: the scalar ``final``
        metrics, then the last chunk's, as many as fit 100 columns. Every metric stays in
        ``summary.json``.
      paper_rows: ``RunResult -> list[PaperRow]``: the paper's numbers beside the run's, for
        ``vbl report``, which rebuilds the ``RunResult`` from a run folder's ``config.json``
        and ``summary.json`` (``curves`` empty; ``final`` from the per-seed values).
      presets: ``{name: {path: value}}``: named variants (``vbl run NAME --preset P``);
        ``--set`` overrides a preset's values and ``--sweep`` of one of its paths replaces
        it.
      published_presets: the presets whose results the README publishes: ``vbl reproduce``
        runs each of them beside the default config (into ``<out>/<name>-<preset>``).
      report_reads: run folders beside this run's (in a ``vbl reproduce`` folder) whose
        results its ``report`` reads (:func:`vbl.engine.rebuild.sibling_result`): ``vbl
        reproduce`` builds this run's report again once every run has finished.
    """

    name: str
    description: str
    default_config: Config
    make_program: Callable[[Config], Program] | None = None
    run: Callable[[RunContext], dict[str, Any]] | None = None
    quick: Mapping[str, Any] = field(default_factory=dict)
    seeds: int = 8
    quick_seeds: int | None = None
    paper_result: bool = False
    in_quick_reproduce: bool = True
    paper: Mapping[str, Any] | None = None
    report: Callable[[RunResult], ReportSection] | None = None
    sweep: Mapping[str, tuple[Any, ...] | list[Any]] = field(default_factory=dict)
    group: str | None = None
    percent: bool = False
    headline: tuple[str, ...] = ()
    paper_rows: Callable[[RunResult], list[PaperRow]] | None = None
    presets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    published_presets: tuple[str, ...] = ()
    report_reads: tuple[str, ...] = ()

    def preset(self, name: str | None, swept: Any = ()) -> dict[str, Any]:
        """The ``{path: value}`` overrides of preset ``name`` ({} for None) but the paths in
        ``swept`` (a sweep replaces a preset's value); an unknown name is a ParamError that
        lists the valid ones."""
        if name is None:
            return {}
        if name not in self.presets:
            valid = ", ".join(sorted(self.presets)) or "(none)"
            raise ParamError(f"unknown preset {name!r} for {self.name}; valid: {valid}")
        return {k: v for k, v in self.presets[name].items() if k not in swept}

    def __post_init__(self) -> None:
        if not re.fullmatch(r"[A-Za-z0-9_\-]+", self.name or ""):
            raise ValueError(f"Experiment.name must use letters, digits, '_' or '-', "
                             f"got {self.name!r}")
        if (self.make_program is None) == (self.run is None):
            raise ValueError(f"experiment {self.name!r}: give exactly one of make_program "
                             f"and run")
        if not dataclasses.is_dataclass(self.default_config) or isinstance(
                self.default_config, type):
            raise ValueError(f"experiment {self.name!r}: default_config must be a flax.struct "
                             f"dataclass instance, got {type(self.default_config).__name__}")
        checked = [(f"presets[{n!r}]", p) for n, v in self.presets.items() for p in v]
        for what, path in checked:
            try:
                get_path(self.default_config, path)
            except ParamError as e:
                raise ValueError(f"experiment {self.name!r}: {what}: {e}") from None
        unknown = [p for p in self.published_presets if p not in self.presets]
        if unknown:
            raise ValueError(f"experiment {self.name!r}: published_presets {unknown} are not "
                             f"presets; valid: {sorted(self.presets)}")
        for n, v in (("seeds", self.seeds), ("quick_seeds", self.quick_seeds)):
            if v is not None and (not isinstance(v, int) or v < 1):
                raise ValueError(f"experiment {self.name!r}: {n} must be an int >= 1, got {v!r}")
