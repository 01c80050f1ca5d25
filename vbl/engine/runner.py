"""Run an experiment: resolve the config, plan the sweep, run every group's chunks vmapped,
jitted and sharded, checkpoint, log metrics, summarise and plot."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import math
import shlex
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np
from jax.experimental import multihost_utils

from vbl.engine.config import (
    INT32,
    apply_overrides,
    config_to_dict,
    fingerprint,
    traced_dtype,
)
from vbl.engine.errors import EngineError, stop_hint, stop_message
from vbl.engine.experiment import Experiment, RunContext, RunResult
from vbl.engine.jax_setup import (
    COMPILER_OPTIONS,
    compile_shared,
    engine_precision,
    execution_turn,
)
from vbl.engine.memory import check_memory, tree_bytes
from vbl.engine.plots import plot_curves, plot_names
from vbl.engine.process import one_device_hint
from vbl.engine.progress import STATUS_FILE, Progress, auto_quiet
from vbl.engine.registry import source_file
from vbl.engine.report import write_report
from vbl.engine.results import (
    MetricsLog,
    metric_arrays,
    point_summaries,
    read_json,
    read_metrics,
    seed_stats,
    write_json,
)
from vbl.engine.runfolder import (
    DEFAULT_CHECKPOINT_EVERY,
    DEFAULT_LEARNER_BATCH,
    RUN_FORMAT,
    RunFolder,
    check_fingerprint,
    check_format,
    differing,
    open_run_folder,
)
from vbl.engine.sharding import batch_layout, learner_sharding, pad_index, put, to_host
from vbl.engine.sweep import Group, Shard, SweepPlan, make_plan, parse_shard
from vbl.engine.trace_cache import code_key, traced
from vbl.params import ParamError

if TYPE_CHECKING:  # the checkpoint library loads with the first run, not with the module
    from vbl.engine.checkpoint import Checkpoints

__all__ = ["run_experiment", "resolve", "describe_sweep", "load_result", "defaults_spec",
           "shard_spec", "whole_spec"]

ONCE_LEARNER_BATCH = 64
"""Most learners per device that a program's ``init``, ``begin_final`` and ``final`` (run
once per group) compute at once: larger batches run as a loop over vmapped batches of this
size (``jax.lax.map``), which bounds their memory (Table 2's ``init``, data collection and
identification, needs about 23 MB per learner); each learner's result is what it gets
alone, to float rounding, and with fewer learners per device the program is the plain
``vmap``. ``step`` vmaps all its learners at once."""


def resolve(experiment: Experiment, sets: Mapping[str, Any] | None = None,
            sweep: Mapping[str, Sequence[Any]] | None = None, seeds: int | None = None,
            base_seed: int = 0, quick: bool = False, preset: str | None = None
            ) -> tuple[Any, dict, int, dict]:
    """``(config, sweep, seeds, spec)``: defaults + quick overrides + the values of
    ``preset`` + ``sets``, validated; ``spec`` is the JSON description (``config.json``)
    whose fingerprint guards checkpoints; it records the run-folder format
    :data:`~vbl.engine.runfolder.RUN_FORMAT` and the preset.

    The sweep is the experiment's default sweep with ``sweep`` replacing the paths it names;
    a path of the default sweep that ``sets`` (or, with ``quick``, the experiment's
    ``quick``) fixes leaves the sweep (one value). A path
    both in ``sets`` and in ``sweep`` is an error; a preset's path that ``sweep`` names
    takes the sweep's values.
    """
    config = experiment.default_config
    if quick:
        config = apply_overrides(config, experiment.quick)
    config = apply_overrides(config, experiment.preset(preset, sweep or {}))
    config = apply_overrides(config, sets or {})
    both = sorted(set(sets or {}) & set(sweep or {}))
    if both:
        p = both[0]
        raise ParamError(f"{p} is both set and swept (sweep values {list(sweep[p])}); choose "
                         f"its values with --sweep {p}=V1,V2,... alone")
    fixed = {*(sets or {}), *(experiment.quick if quick else {})}
    full_sweep = {p: list(v) for p, v in experiment.sweep.items() if p not in fixed}
    full_sweep.update({p: list(v) for p, v in (sweep or {}).items()})
    if seeds is None:
        seeds = experiment.quick_seeds if (quick and experiment.quick_seeds) else experiment.seeds
    spec = {"format": RUN_FORMAT, "experiment": experiment.name, "preset": preset,
            "quick": bool(quick), "config": config_to_dict(config), "sweep": full_sweep,
            "seeds": seeds, "base_seed": base_seed}
    spec["fingerprint"] = fingerprint(spec)
    return config, full_sweep, seeds, spec


def describe_sweep(experiment: Experiment, sets: Mapping[str, Any] | None = None,
                   sweep: Mapping[str, Sequence[Any]] | None = None, seeds: int | None = None,
                   quick: bool = False, preset: str | None = None) -> tuple[int, int, str]:
    """``(points, seeds, text)``: what a run will sweep, said before it starts: every swept
    path with its values and where they come from (``--sweep`` or the experiment's default
    sweep, which ``--set PATH=V`` fixes), the number of points and seeds."""
    _, full, seeds, _ = resolve(experiment, sets, sweep, seeds, 0, quick, preset)
    points = math.prod(len(v) for v in full.values()) if full else 1
    head = (f"{experiment.name}: {points} sweep point{'s' * (points != 1)} x {seeds} "
            f"seed{'s' * (seeds != 1)} = {points * seeds} learners")
    lines = [head]
    for path, values in full.items():
        shown = ",".join(str(v) for v in values[:8]) + (",..." if len(values) > 8 else "")
        where = "--sweep" if path in (sweep or {}) else "the experiment's default sweep"
        lines.append(f"  {path} = {shown} ({where})")
    if set(full) - set(sweep or {}):
        lines.append("  (a default-swept PATH: --sweep PATH=... replaces its values, --set "
                     "PATH=V fixes it)")
    return points, seeds, "\n".join(lines)


def _sync(name: str) -> None:
    if jax.process_count() > 1:
        multihost_utils.sync_global_devices(name)


def _in_engine_precision(fn):
    """Run ``fn`` inside :func:`vbl.engine.jax_setup.engine_precision`."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with engine_precision():
            return fn(*args, **kwargs)
    return wrapper


@_in_engine_precision
def run_experiment(experiment: Experiment, *, sets: Mapping[str, Any] | None = None,
                   sweep: Mapping[str, Sequence[Any]] | None = None, seeds: int | None = None,
                   base_seed: int = 0, out: str | Path | None = None, resume: bool = False,
                   overwrite: bool = False, quick: bool = False, quiet: bool | None = None,
                   checkpoint_every: int = DEFAULT_CHECKPOINT_EVERY,
                   learner_batch: int = DEFAULT_LEARNER_BATCH, plots: bool = True,
                   memory_check: bool = True, preset: str | None = None,
                   shard: Shard | str | None = None,
                   tensorboard: str | Path | None = None, zipped: bool = False,
                   span: tuple[int, int] | None = None,
                   start_carry: Callable[[Any], Any] | None = None,
                   report: bool = True) -> RunResult:
    """Run ``experiment`` over ``sweep`` x ``seeds`` and write its run folder, with its
    ``report.md`` as ``vbl run`` writes it.

    Args:
      sets: ``{dotted.path: value}`` overrides (validated). ``sweep``: ``{path: [values]}``
        (the grid is the product). ``seeds``: seeds per sweep point (default: the
        experiment's). ``base_seed``: see :func:`vbl.engine.sweep.learner_keys`.
      preset: a name of ``experiment.presets`` (its values under ``sets``).
      out: run folder (default ``runs/<name>-<timestamp>``). ``resume``: continue from the
        folder's last checkpoint. ``overwrite``: replace a run folder vbl wrote.
      checkpoint_every: chunks between checkpoints. ``learner_batch``: most learners per
        compiled call (larger grids run in several batches; same results).
      memory_check: refuse a run whose memory estimate exceeds the memory available
        (:mod:`vbl.engine.memory`).
      shard: ``"i/N"`` (or a :class:`~vbl.engine.sweep.Shard`): run only the i-th of N
        parts of the learners, with the keys of the whole run; its folder holds metric
        rows for :func:`vbl.engine.merge.merge_runs` and no report.
      tensorboard: a folder for TensorBoard event files: each sweep point's mean curve and
        95 % band per chunk, written as the run goes (:mod:`vbl.engine.tensorboard`).
      zipped: the sweep's values side by side, one point per value (every path the same
        number of values), not their product: a list of points (``vbl tune``'s trials).
      span: ``(first, last)``: run only chunks ``first`` to ``last - 1`` of a one-group
        plan (``Program.final`` only when ``last`` is the program's ``num_chunks``); with
        ``first > 0`` the carries at chunk ``first`` come from ``start_carry(like)``, a host
        tree shaped like ``like`` (the group's carries, ``[learners, ...]``). Both are
        recorded in ``config.json``.
      quiet: no progress bar (None: quiet when stderr is no terminal or Jupyter kernel,
        or ``CI`` is set), as ``vbl run``. Not quiet, a run on one CPU device of a
        machine with more cores prints one hint: :func:`vbl.engine.use_all_cores`.
      report: write ``report.md`` (:func:`vbl.engine.report.run_report`; a shard writes
        none).
    Everything is checked (values, memory, folder) before the folder is written; the folder
    is locked while the run writes it (:mod:`vbl.engine.runfolder`).
    Returns: a :class:`RunResult` (curves/final as NumPy arrays, on process 0; empty for a
    shard).
    Raises: ParamError (bad overrides), EngineError / CheckpointError (folder, checkpoint,
    memory).
    """
    _check_options(checkpoint_every, learner_batch, tensorboard, out)
    primary = jax.process_index() == 0
    config, full_sweep, seeds, spec = resolve(experiment, sets, sweep, seeds, base_seed, quick,
                                              preset)
    shard = shard if shard is None or isinstance(shard, Shard) else parse_shard(shard)
    spec, plan = _plan(experiment, config, full_sweep, seeds, base_seed,
                       _partial_spec(spec, zipped, span), shard, zipped)
    _check_span(plan, span, start_carry)
    if plan is not None and memory_check:
        check_memory(plan, _state_bytes(experiment, learner_sharding(), learner_batch))
    if plan is not None:
        plan.validate()
    quiet = _quiet(quiet, primary)

    folder = open_run_folder(out, experiment.name, resume=resume, overwrite=overwrite,
                             primary=primary)
    run = _Run(folder, experiment, config, full_sweep, seeds, base_seed, spec, plan, resume,
               quick, quiet, checkpoint_every, learner_batch, plots, primary,
               None if tensorboard is None else Path(tensorboard),
               None if span is None else (int(span[0]), int(span[1])), start_carry)
    try:
        result = _run_in(run)
        if report and primary and shard is None:
            write_report(experiment, result, "run")
        return result
    finally:
        folder.release()


def _plan(experiment: Experiment, config: Any, sweep: dict, seeds: int, base_seed: int,
          spec: dict, shard: Shard | None, zipped: bool) -> tuple[dict, SweepPlan | None]:
    """``(spec, plan)``: a shard's spec (:func:`shard_spec`) and the sweep's plan (None for
    an experiment's own loop, which cannot be sharded)."""
    if shard is not None:
        if experiment.make_program is None:
            raise ParamError(f"{experiment.name} runs its own loop (Experiment.run): --shard "
                             f"needs an experiment with make_program")
        spec = shard_spec(spec, shard)
    if experiment.make_program is None:
        return spec, None
    return spec, make_plan(experiment, config, sweep, seeds, base_seed, shard, zipped)


def _quiet(quiet: bool | None, primary: bool) -> bool:
    """Whether the run shows no progress (the rule of ``vbl run``); not quiet, a run on
    one CPU device of a machine with more cores prints how to use them, once."""
    quiet = (auto_quiet() if quiet is None else quiet) or not primary
    hint = None if quiet else one_device_hint()
    if hint:
        print(hint, file=sys.stderr, flush=True)
    return quiet


def _check_options(checkpoint_every: Any, learner_batch: Any, tensorboard: Any,
                   out: Any) -> None:
    _check_chunking(checkpoint_every, learner_batch)
    if tensorboard is not None:
        from vbl.engine.tensorboard import require_tensorboardx

        require_tensorboardx()
    if jax.process_count() > 1 and out is None:
        raise EngineError("a multi-process run needs --out on a shared file system")


def _check_chunking(checkpoint_every: Any, learner_batch: Any) -> None:
    for name, v in (("checkpoint_every", checkpoint_every), ("learner_batch", learner_batch)):
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= INT32[1]:
            raise ParamError(f"{name} must be an int in [1, {INT32[1]}], got {v!r}")


def _partial_spec(spec: dict, zipped: bool, span: tuple[int, int] | None) -> dict:
    """``spec`` with ``"zipped"`` and ``"span"`` recorded (when given) and its fingerprint
    again; unchanged otherwise."""
    if not zipped and span is None:
        return spec
    out = {k: v for k, v in spec.items() if k != "fingerprint"}
    if zipped:
        out["zipped"] = True
    if span is not None:
        out["span"] = [int(x) for x in span]
    out["fingerprint"] = fingerprint(out)
    return out


def _check_span(plan: SweepPlan | None, span: Any, start_carry: Any) -> None:
    """ParamError unless ``span`` is None or ``(first, last)`` within a one-group plan's
    chunks, with ``start_carry`` when ``first > 0``."""
    if span is None:
        return
    if plan is None or plan.shard is not None or len(plan.groups) != 1:
        raise ParamError("a span of chunks needs a program run in one compile group, "
                         "unsharded")
    first, last = span
    n = plan.groups[0].num_chunks
    if not (isinstance(first, int) and isinstance(last, int) and 0 <= first < last <= n):
        raise ParamError(f"span {span!r}: needs 0 <= first < last <= {n} (the chunks)")
    if first > 0 and start_carry is None:
        raise ParamError("a span that starts after chunk 0 needs start_carry")


def shard_spec(spec: dict, shard: Shard) -> dict:
    """``spec`` (a whole run's ``config.json``) with ``shard``: ``{"index", "count",
    "commit"}`` (the git commit of the code, as ``vbl reproduce`` records it) and its own
    fingerprint, so a shard resumes only as the same part from the same code."""
    from vbl.engine.machine import git_commit

    out = {k: v for k, v in spec.items() if k != "fingerprint"}
    out["shard"] = {"index": shard.index, "count": shard.count, "commit": git_commit()}
    out["fingerprint"] = fingerprint(out)
    return out


def whole_spec(spec: dict) -> dict:
    """The ``config.json`` of the whole run a shard's ``spec`` is part of."""
    out = {k: v for k, v in spec.items() if k not in ("shard", "fingerprint")}
    out["fingerprint"] = fingerprint(out)
    return out


@dataclass(frozen=True)
class _Run:
    """What a run needs once its config is resolved, its plan built and its folder open
    (``plan`` is None for an experiment's own loop, ``Experiment.run``)."""

    folder: RunFolder
    experiment: Experiment
    config: Any
    sweep: dict
    seeds: int
    base_seed: int
    spec: dict
    plan: SweepPlan | None
    resume: bool
    quick: bool
    quiet: bool
    checkpoint_every: int
    learner_batch: int
    plots: bool
    primary: bool
    tensorboard: Path | None = None  # TensorBoard event files' folder
    span: tuple[int, int] | None = None  # chunks [first, last) of a one-group plan
    start_carry: Callable[[Any], Any] | None = None  # the carries at chunk ``first``

    @property
    def path(self) -> Path:
        return self.folder.path


def _check_config_json(run_dir: Path, spec: dict) -> bool:
    """On resume: compare ``config.json`` with ``spec``; False when it is missing."""
    cfg_path = run_dir / "config.json"
    if not cfg_path.exists():
        return False
    try:
        old = read_json(cfg_path)
        if not isinstance(old, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as e:
        raise EngineError(f"cannot resume {run_dir}: its config.json is unreadable "
                          f"({type(e).__name__}: {e}); restore it, or start again with "
                          f"--overwrite / another --out") from None
    check_format(old, run_dir)
    check_fingerprint(old, run_dir, [spec, *defaults_spec(old)])  # a hand-edited file
    if old.get("fingerprint") != spec["fingerprint"]:
        diff = differing(old, spec)
        shown = str(diff[:8] + (["..."] if len(diff) > 8 else [])) if diff else \
            "its fingerprint only"
        if not diff and old.get("shard") != spec.get("shard"):
            shown = f"its shard: {_shard_text(old)}, this run {_shard_text(spec)}"
        raise EngineError(f"cannot resume {run_dir}: it was run with another config "
                          f"(differs in {shown}); use the same options, or "
                          f"--overwrite / another --out")
    return True


def _shard_text(spec: dict) -> str:
    sh = spec.get("shard")
    if not isinstance(sh, dict):
        return "no shard"
    return f"part {sh.get('index')}/{sh.get('count')} from commit {sh.get('commit')}"


def defaults_spec(spec: dict) -> list[dict]:
    """The ``config.json`` of ``spec``'s experiment at its defaults (with the recorded
    ``--quick`` and preset), one dict, to compare an edited ``config.json`` with; none when
    the experiment or the preset is unknown."""
    from vbl.engine.registry import get

    try:
        exp = get(str(spec.get("experiment")))
        return [resolve(exp, None, None, None, 0, bool(spec.get("quick")),
                        spec.get("preset"))[3]]
    except Exception:  # noqa: BLE001 - only a hint for the error line
        return []


def _run_in(run: _Run) -> RunResult:
    """Write ``config.json`` (checked on resume), then run the chunks and summarise (or
    the experiment's own loop)."""
    ckpts = _start_folder(run)
    run.folder.record("metrics.jsonl")
    log = MetricsLog(run.path / "metrics.jsonl", enabled=run.primary)
    if run.tensorboard is not None and run.primary:
        from vbl.engine.tensorboard import TensorBoardLog

        log = TensorBoardLog(log, run.tensorboard)
    t_start = time.perf_counter()
    forget_hint = stop_hint(lambda: _resume_tail(run)) if run.primary else lambda: None
    try:
        if run.plan is None:
            return _run_own_loop(run, log, t_start)
        start = _train(run, ckpts, log)
    except KeyboardInterrupt as e:  # SIGINT, or SIGTERM (Terminated): say how to go on
        if run.primary:
            raise type(e)(f"{stop_message(e)}; {_resume_tail(run)}") from None
        raise
    finally:
        forget_hint()
        if hasattr(log, "close"):
            log.close()
    return _summarise(run, start, time.perf_counter() - t_start)


def _resume_tail(run: _Run) -> str:
    """What a stopped run's line says after the stop: the chunk whose checkpoint is kept
    and the command that continues it (``vbl run ... --out FOLDER --resume``)."""
    from vbl.engine.rebuild import run_command  # rebuild imports this module

    steps = [int(d.name) for d in (run.path / "checkpoints").glob("*") if d.name.isdigit()]
    kept = (f"the checkpoint of chunk {max(steps)} is kept in {run.path}" if steps else
            f"no chunk was checkpointed yet in {run.path}")
    try:
        command = run_command(run.experiment, run.spec)
    except Exception:  # noqa: BLE001 - the line must not fail; a shorter command then
        command = f"vbl run {run.experiment.name} ..."
    return f"{kept}; continue with: {command} --out {shlex.quote(str(run.path))} --resume"


def _start_folder(run: _Run) -> Checkpoints | None:
    """Check (on resume) and write ``config.json``; the checkpoints of a planned run."""
    has_config = run.resume and run.primary and _check_config_json(run.path, run.spec)
    ckpts = None
    if run.plan is not None:
        from vbl.engine.checkpoint import Checkpoints

        ckpts = Checkpoints(run.path / "checkpoints", run.spec["fingerprint"])
        run.folder.record("checkpoints")
        if run.resume and not has_config and ckpts.latest_step() is not None:
            ckpts.check_meta(ckpts.latest_step())  # before config.json is written
    if run.primary and not has_config:
        run.folder.record("config.json")
        write_json(run.path / "config.json", run.spec)
    _sync("vbl-run-dir")
    return ckpts


def _run_own_loop(run: _Run, log: MetricsLog, t_start: float) -> RunResult:
    """The escape hatch: ``Experiment.run`` writes what it likes; its return value goes
    to ``summary.json``."""
    run_dir, primary = run.path, run.primary
    if primary and not run.resume:
        (run_dir / "metrics.jsonl").unlink(missing_ok=True)

    def log_fn(step, metrics):
        log.append([{"step": int(step), "metrics": dict(metrics)}])

    before = {p.name for p in run_dir.iterdir()}
    ctx = RunContext(run.config, run.seeds, run.base_seed, run_dir, run.quick, log_fn,
                     run.quiet)
    try:
        extra = run.experiment.run(ctx) or {}
    finally:
        run.folder.record(*({p.name for p in run_dir.iterdir()} - before))
    summary = {"experiment": run.experiment.name, "fingerprint": run.spec["fingerprint"],
               "result": extra, "wall_time_s": time.perf_counter() - t_start}
    if primary:
        run.folder.record("summary.json")
        write_json(run_dir / "summary.json", summary)
    return RunResult(run.experiment.name, run_dir, run.config, run.sweep, [{}], run.seeds,
                     {}, {}, summary, sorted(run_dir.glob("*.png")), dict(extra))


def _train(run: _Run, ckpts: Checkpoints, log: MetricsLog) -> int:
    """Run every group's chunks from the last checkpoint (on resume); return the global
    step the run started from."""
    plan = run.plan
    start = (ckpts.latest_step() or 0) if run.resume else 0
    if start and run.primary and not run.quiet:
        print(f"{run.experiment.name}: resuming after chunk {start} (its checkpoint in "
              f"{run.path})", file=sys.stderr, flush=True)
    run.folder.record(STATUS_FILE)
    total, done = _steps_to_run(plan, start, run.span)
    progress = Progress(total, done, run.experiment.name, run.quiet,
                        status_dir=run.path if run.primary else None)
    sharding = learner_sharding()
    truncate = run.resume and run.primary
    try:
        for i, group in enumerate(g for g in plan.groups if g.num_learners
                                  and g.step_offset + _last(g, run.span) > start):
            if i:
                progress.compiling()
            _run_group(plan, group, sharding, ckpts, log, progress, start,
                       run.checkpoint_every, run.learner_batch, truncate, run.span,
                       run.start_carry, _ident(run.experiment, group))
            truncate = False  # once, before the first new row
    except BaseException:
        progress.close()
        with contextlib.suppress(Exception):  # the first error is the one to report
            ckpts.close()
        raise
    progress.close()
    ckpts.close()
    return start


def _last(group: Group, span: tuple[int, int] | None) -> int:
    """The chunk a group's run ends at: its program's last, or the span's."""
    return group.num_chunks if span is None else span[1]


def _steps_to_run(plan: SweepPlan, start: int, span: tuple[int, int] | None = None
                  ) -> tuple[int, int]:
    """``(steps, steps done)`` of the groups that have learners (a shard's may not), the
    run resuming from global step ``start`` (a span's chunks before its first count as
    done)."""
    groups = [g for g in plan.groups if g.num_learners]
    first = 0 if span is None else span[0]
    return (sum(_last(g, span) for g in groups),
            sum(min(_last(g, span), max(first, start - g.step_offset)) for g in groups))


def _summarise(run: _Run, start: int, wall: float) -> RunResult:
    """``summary.json`` (and the plots) from ``metrics.jsonl``; a shard's only says what
    ran."""
    plan = run.plan
    _sync("vbl-run-done")
    how = {"wall_time_s": wall, "resumed_from_step": start, "learners": plan.num_learners,
           "devices": jax.device_count(), "processes": jax.process_count()}
    steps, done = _steps_to_run(plan, start, run.span)
    recorded = _recorded_summary(run.path) if run.resume and done == steps else None
    if recorded is not None:  # a finished run resumed: nothing ran, its record stands
        how.update({k: recorded[k] for k in HOW_RAN if k in recorded})
    if plan.shard is not None:
        if recorded is not None and "metrics_sha256" in recorded:
            return RunResult(run.experiment.name, run.path, run.config, plan.sweep,
                             plan.points, plan.seeds, {}, {}, recorded, [])
        summary = {"experiment": run.experiment.name, "shard": run.spec["shard"],
                   "chunks": plan.total_steps, **how,
                   "metrics_sha256": metrics_line_sums(run.path / "metrics.jsonl")}
        result = RunResult(run.experiment.name, run.path, run.config, plan.sweep, plan.points,
                           plan.seeds, {}, {}, summary, [])
    else:
        result = load_result(run.path, run.experiment, run.config, plan,
                             plots=run.plots and run.primary, folder=run.folder)
        result.summary.update(how)
    if run.primary:
        run.folder.record("summary.json")
        write_json(run.path / "summary.json", result.summary)
    return result


HOW_RAN = ("wall_time_s", "resumed_from_step", "devices", "processes")
"""The entries of ``summary.json`` that say how the run ran (kept by a ``--resume`` of a
finished run, which runs nothing)."""


def _recorded_summary(run_dir: Path) -> dict | None:
    """The ``summary.json`` a finished run wrote, if it is readable."""
    try:
        old = read_json(run_dir / "summary.json")
    except (OSError, ValueError):
        return None
    return old if isinstance(old, dict) else None


def metrics_line_sums(path: Path) -> list[str]:
    """The sha256 (first 16 hex digits) of each line of the ``metrics.jsonl`` at ``path``:
    a shard records them when it finishes, and ``vbl merge`` checks them."""
    lines = Path(path).read_bytes().split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    return [hashlib.sha256(x).hexdigest()[:16] for x in lines]


def _run_group(plan: SweepPlan, group: Group, sharding, ckpts: Checkpoints, log: MetricsLog,
               progress: Progress, start: int, every: int, learner_batch: int,
               truncate: bool = False, span: tuple[int, int] | None = None,
               start_carry: Callable[[Any], Any] | None = None, ident: str = "") -> None:
    """Run ``group`` from global step ``start`` (to the end of ``span`` when given); with
    ``truncate``, drop the rows of ``metrics.jsonl`` past ``start`` once the checkpoint is
    restored (a checkpoint that cannot be restored leaves the file as it was). ``ident``
    names the program for the trace cache (:func:`_ident`)."""
    prog = group.program
    n = group.num_learners
    batches, gather = _batching(n, sharding, learner_batch)
    init_keys = group.select(plan.init_keys)
    final_keys = group.select(plan.final_keys)
    init_fn, step_fn, final_fn, begin_fn = _compiled(prog, sharding)
    cfgs = batches(group.configs)
    first, end = (0, prog.num_chunks) if span is None else span
    done = max(first, start - group.step_offset)
    if done > 0:
        shape = jax.eval_shape(jax.vmap(prog.init), jax.ShapeDtypeStruct((n, 2), np.uint32),
                               jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype),
                                            group.configs))
        like = jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), shape)
        if done > first:
            carry_host, _ = ckpts.restore(start, like)
        else:
            carry_host = start_carry(like)
        carries = batches(carry_host)
    else:
        keys = batches(init_keys)
        init_fn = _ready(init_fn, ident, "init", keys[0], cfgs[0])
        with execution_turn():
            carries = jax.block_until_ready([init_fn(k, c) for k, c in
                                             zip(keys, cfgs, strict=True)])
    if truncate:
        log.truncate_after(start)

    if done < end:
        step_fn = _ready(step_fn, ident, "step", carries[0], cfgs[0])
    for chunk in range(done, end):
        t0 = time.perf_counter()
        with execution_turn():
            outs = jax.block_until_ready([step_fn(c, cfg) for c, cfg in
                                          zip(carries, cfgs, strict=True)])
        carries = [o[0] for o in outs]
        metrics = gather([o[1] for o in outs])
        dt = time.perf_counter() - t0
        step = group.step_offset + chunk + 1
        log.append(_rows(plan, group, step, chunk, metrics))
        progress.update(metrics, dt, prog.progress_metric)
        last = chunk + 1 == end
        if chunk + 1 == prog.num_chunks and prog.final is not None:
            keys = batches(final_keys)
            done_carries = _final_carries(prog, begin_fn, step_fn, ident, carries, cfgs, keys)
            final_fn = _ready(final_fn, ident, "final", done_carries[0], cfgs[0], keys[0])
            with execution_turn():
                fin = gather([final_fn(c, cfg, k) for c, cfg, k in
                              zip(done_carries, cfgs, keys, strict=True)])
            log.append(_rows(plan, group, step, "final", fin))
        if last or (chunk + 1) % every == 0:
            ckpts.save(step, gather(carries), {"group": group.index, "chunk": chunk + 1})


def _final_carries(prog, begin_fn, step_fn, ident: str, carries: list, cfgs: list,
                   keys: list) -> list:
    """The carries that ``final`` reads: ``carries`` themselves, or for a program with
    ``begin_final`` the carries after it and ``final_steps`` compiled steps."""
    if prog.begin_final is None:
        return carries
    begin_fn = _ready(begin_fn, ident, "begin_final", carries[0], cfgs[0], keys[0])
    with execution_turn():
        carries = [begin_fn(c, cfg, k) for c, cfg, k in zip(carries, cfgs, keys, strict=True)]
        for _ in range(prog.final_steps):
            carries = [step_fn(c, cfg)[0] for c, cfg in zip(carries, cfgs, strict=True)]
        return jax.block_until_ready(carries)


def _batching(n: int, sharding, learner_batch: int) -> tuple[Callable, Callable]:
    """``(batches, gather)`` for ``n`` learners: ``batches`` splits a host tree ``[n, ...]``
    into per-batch device trees ``[size, ...]`` (:func:`batch_layout`, padded with copies of
    learner 0); ``gather`` joins per-batch device trees back into a host tree ``[n, ...]``."""
    nb, size = batch_layout(n, len(sharding.mesh.devices.flat), learner_batch)
    idx = pad_index(n, nb * size)

    def batches(tree):
        padded = jax.tree.map(lambda x: np.asarray(x)[idx], tree)
        return [put(jax.tree.map(lambda x, b=b: x[b * size:(b + 1) * size], padded), sharding)
                for b in range(nb)]

    def gather(trees):
        host = [to_host(t) for t in trees]
        return jax.tree.map(lambda *xs: np.concatenate(xs)[:n], *host)
    return batches, gather


def _state_bytes(experiment: Experiment, sharding, learner_batch: int
                 ) -> Callable[[Group], int]:
    """The memory check's size of one learner's state of a group (bytes): the output
    shapes of the per-device ``init`` that the run calls, for the arguments of its first
    batch, through the trace cache. The run then reuses that trace (or a warm run's
    program read back), so ``init`` is traced once, not once for the check and again to
    run. No learner's arrays are made (shape-dtype structs, as a refused run needs)."""
    def state_bytes(group: Group) -> int:
        _, size = batch_layout(group.num_learners, len(sharding.mesh.devices.flat),
                               learner_batch)

        def arg(shape, dtype):
            return jax.ShapeDtypeStruct((size, *shape), dtype, sharding=sharding)
        keys = arg((2,), np.uint32)
        cfgs = jax.tree.map(lambda x: arg(np.shape(x), traced_dtype(x)), group.first_config)
        init_fn = _cached(_compiled(group.program, sharding)[0], _ident(experiment, group),
                          "init", keys, cfgs)
        return tree_bytes(init_fn.eval_shape(keys, cfgs)) // size
    return state_bytes


def _ident(experiment: Experiment, group: Group) -> str:
    """A group's program for the trace cache: the experiment's name, the code of its
    script's folder, the module its config class comes from (a program read back finds its
    classes by module and name: a script imported under another module name, from another
    path, has other classes) and the group's config (the ``vbl`` sources are in every
    key); "" (not cached) for an experiment registered from no script."""
    src = source_file(experiment.name)
    return (f"{experiment.name} {code_key(Path(src).parent)} "
            f"{type(group.base_config).__module__} {group.base_config!r}" if src else "")


def _cached(fn, ident: str, name: str, *args):
    """``fn``, the program ``name`` (``init``, ``step``, ``final``) of the group ``ident``
    (:func:`_ident`), as the call of its program in the trace cache when it is on
    (:func:`vbl.engine.trace_cache.traced`); ``fn`` itself for a group with no ident (an
    experiment registered from no script is never cached)."""
    return traced(fn, f"{ident} {name}", *args) if ident else fn


def _ready(fn, ident: str, name: str, *args):
    """:func:`_cached` ``fn``, compiled for ``args`` (:func:`compile_shared`)."""
    fn = _cached(fn, ident, name, *args)
    compile_shared(fn, *args)
    return fn


_JITTED: dict[tuple, tuple] = {}


def _per_device(fn, sharding, batch: int | None = None):
    """``jit(vmap(fn))`` over the learner axis, each device running its own learners
    (``shard_map``): the learners are independent, so no device waits for another, also
    not in a loop whose trip count depends on the data (a ``while_loop`` vmapped over
    learners runs until its last learner is done: over the global learner axis that is a
    cross-device reduction per iteration). With ``batch``, a device's learners run in
    vmapped batches of at most ``batch`` (``jax.lax.map``)."""
    spec = sharding.spec
    if batch is None:
        per_device = jax.vmap(fn)
    else:
        def per_device(*args):
            return jax.lax.map(lambda a: fn(*a), args, batch_size=batch)
    # check_vma off: the learner programs use no collectives, and their loop carries start
    # from constants (which the check would need marked as varying over devices)
    return jax.jit(jax.shard_map(per_device, mesh=sharding.mesh, in_specs=spec,
                                 out_specs=spec, check_vma=False),
                   compiler_options=COMPILER_OPTIONS)


def _compiled(prog, sharding) -> tuple:
    """The per-device ``jit(vmap(...))`` of a program's ``init``, ``step``, ``final`` and
    ``begin_final`` (:func:`_per_device`; None for a missing one), cached per (program,
    sharding)."""
    key = (id(prog), sharding)
    if key not in _JITTED:
        once = ONCE_LEARNER_BATCH
        final, begin = ((None if f is None else _per_device(f, sharding, once))
                        for f in (prog.final, prog.begin_final))
        _JITTED[key] = (_per_device(prog.init, sharding, once),
                        _per_device(prog.step, sharding), final, begin,
                        prog)  # keeps prog alive so its id stays unique
    return _JITTED[key][:4]


def _rows(plan: SweepPlan, group: Group, step: int, chunk: int | str,
          metrics: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """One row per point of ``group.members``: the statistics over its seeds that ran (a
    shard's rows also say which, ``"seeds": [first, end]``)."""
    rows, at = [], 0
    for p, lo, hi in group.members:
        row: dict[str, Any] = {"step": step, "group": group.index, "chunk": chunk, "point": p}
        if plan.shard is not None:
            row["seeds"] = [lo, hi]
        row["values"] = plan.points[p]
        row["metrics"] = {k: seed_stats(np.asarray(v)[at:at + hi - lo])
                          for k, v in metrics.items()}
        rows.append(row)
        at += hi - lo
    return rows


def load_result(run_dir: Path, experiment: Experiment, config: Any, plan: SweepPlan,
                plots: bool = True, folder: RunFolder | None = None) -> RunResult:
    """Rebuild curves/final arrays from ``metrics.jsonl``; write plots and the summary dict."""
    rows = read_metrics(run_dir / "metrics.jsonl")
    for i, r in enumerate(rows, 1):
        if not (isinstance(r.get("point"), int) and 0 <= r["point"] < len(plan.points)
                and isinstance(r.get("metrics"), dict)
                and (r.get("chunk") == "final" or isinstance(r.get("chunk"), int))):
            raise EngineError(f"{run_dir / 'metrics.jsonl'} line {i} is not a metrics row of "
                              f"this run; restore the file, or start again with --overwrite")
    chunks = max(g.num_chunks for g in plan.groups)
    curves, final = metric_arrays(rows, len(plan.points), chunks)
    points = point_summaries(curves, final, plan.points)
    if plots and curves:
        if folder is not None:
            folder.record(*plot_names(curves))
        figures = plot_curves(curves, plan.points, run_dir, experiment.name,
                              experiment.percent)
    else:
        figures = sorted(run_dir.glob("*.png"))
    summary = {"experiment": experiment.name, "seeds": plan.seeds, "sweep": plan.sweep,
               "chunks": plan.total_steps, "points": points}
    return RunResult(experiment.name, run_dir, config, plan.sweep, plan.points, plan.seeds,
                     curves, final, summary, list(figures))
