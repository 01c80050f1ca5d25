"""Merge independent shards (``vbl run EXP --shard I/N``) into one run folder.

A shard's folder holds ``config.json`` (the whole run's, plus ``"shard": {"index", "count",
"commit"}``), ``metrics.jsonl`` (one row per step and sweep point with the statistics of
its own seeds, ``"seeds": [first, end]``), checkpoints, and a short ``summary.json``.
:func:`merge_runs` checks that the folders are the N parts of one run (same config,
commit and run-folder format; every part once; every part finished), joins every row's
per-seed values and writes the run folder the unsharded run writes: ``config.json``,
``metrics.jsonl`` (the same rows, in the same order), ``summary.json`` (plus
``"shards"``: what each part ran on) and the plots.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vbl.engine.errors import EngineError
from vbl.engine.experiment import Experiment, RunResult
from vbl.engine.jax_setup import engine_precision
from vbl.engine.rebuild import load_run
from vbl.engine.report import write_report
from vbl.engine.results import MetricsLog, read_json, read_metrics, seed_stats, write_json
from vbl.engine.runfolder import check_fingerprint, differing, open_run_folder, read_run_spec
from vbl.engine.runner import defaults_spec, load_result, metrics_line_sums, whole_spec
from vbl.engine.sweep import Shard, SweepPlan, make_plan
from vbl.params import ParamError

__all__ = ["merge_runs"]

HOW = ("wall_time_s", "resumed_from_step", "devices", "processes")
"""The entries of a shard's ``summary.json`` that describe how it ran; the merged summary
adds the shards' wall times, devices and processes, takes the latest step a shard resumed
from, and lists them per shard under ``"shards"``."""


@dataclass
class _Part:
    folder: Path
    spec: dict[str, Any]
    summary: dict[str, Any]

    @property
    def shard(self) -> Shard:
        return Shard(int(self.spec["shard"]["index"]), int(self.spec["shard"]["count"]))

    @property
    def commit(self) -> str:
        return str(self.spec["shard"].get("commit"))


def merge_runs(folders: list[str | Path], out: str | Path, overwrite: bool = False
               ) -> tuple[Experiment, RunResult]:
    """Merge the shard folders ``folders`` (all N parts of one run, any order) into the
    run folder ``out`` (never an existing one, unless ``overwrite`` and vbl wrote it:
    :func:`vbl.engine.runfolder.open_run_folder`).

    Writes ``report.md`` as ``run_experiment`` does for the whole run, and returns
    ``(experiment, RunResult)`` as it does.
    Raises ParamError (one line) for folders that are not the finished parts of one run,
    EngineError when ``out`` cannot be written.
    """
    with engine_precision():
        return _merge(folders, Path(out), overwrite)


def _merge(folders: list[str | Path], out: Path, overwrite: bool
           ) -> tuple[Experiment, RunResult]:
    parts = [_read_part(Path(f)) for f in folders]
    _check_parts(parts, out)
    exp, config = _experiment_config(parts[0].folder)
    whole = whole_spec(parts[0].spec)
    sweep = {p: [tuple(v) if isinstance(v, list) else v for v in vs]
             for p, vs in whole["sweep"].items()}
    plan = make_plan(exp, config, sweep, whole["seeds"], whole["base_seed"])
    rows = _merged_rows(plan, parts)
    folder = open_run_folder(out, exp.name, resume=False, overwrite=overwrite,
                             resumable=False)
    try:
        folder.record("config.json", "metrics.jsonl")
        write_json(out / "config.json", whole)
        _write_rows(out / "metrics.jsonl", rows)
        result = load_result(out, exp, config, plan, plots=True, folder=folder)
        result.summary.update(_how(parts, plan))
        folder.record("summary.json")
        write_json(out / "summary.json", result.summary)
        write_report(exp, result, "merge")
    finally:
        folder.release()
    return exp, result


def _read_part(folder: Path) -> _Part:
    """A finished shard's ``config.json`` (format and fingerprint checked) and summary."""
    try:  # a folder given that is no shard is bad input: ParamError, exit 2
        spec = read_run_spec(folder)
        if "config" not in spec:
            raise EngineError(f"{folder}/config.json is not a vbl run's config")
        check_fingerprint(spec, folder, defaults_spec(spec))
    except EngineError as e:
        raise ParamError(str(e)) from None
    sh = spec.get("shard")
    if not isinstance(sh, dict) or not {"index", "count"} <= set(sh):
        raise ParamError(f"{folder} is a whole run, not a shard (vbl run --shard I/N); "
                         f"there is nothing to merge")
    summary = _finished_summary(folder, sh)
    _check_metrics(folder, sh, summary)
    return _Part(folder, spec, summary)


def _check_metrics(folder: Path, sh: dict[str, Any], summary: dict[str, Any]) -> None:
    """The shard's ``metrics.jsonl`` is the one it finished with: each line's checksum is
    the one its ``summary.json`` recorded."""
    text = f"shard {sh['index']}/{sh['count']} in {folder}"
    again = "restore it, or run that shard again with --overwrite"
    want = summary.get("metrics_sha256")
    if not (isinstance(want, list) and all(isinstance(x, str) for x in want)):
        raise ParamError(f"{text} records no checksum of its metrics.jsonl (its summary.json "
                         f"has no metrics_sha256 list), so its values cannot be verified; "
                         f"run that shard again with --overwrite")
    try:
        got = metrics_line_sums(folder / "metrics.jsonl")
    except OSError as e:
        raise ParamError(f"{text}: cannot read metrics.jsonl ({e.strerror or e}); "
                         f"{again}") from None
    for line, (a, b) in enumerate(zip(got, want, strict=False), 1):
        if a != b:
            raise ParamError(f"{text}: metrics.jsonl line {line} was changed after the shard "
                             f"finished (it does not match the checksum in summary.json); "
                             f"{again}")
    if len(got) != len(want):
        raise ParamError(f"{text}: metrics.jsonl has {len(got)} lines, the shard finished "
                         f"with {len(want)} (lines were "
                         f"{'added' if len(got) > len(want) else 'removed'} after it "
                         f"finished); {again}")


def _finished_summary(folder: Path, sh: dict[str, Any]) -> dict[str, Any]:
    text = f"{sh['index']}/{sh['count']}"
    again = (f"finish it: run its vbl run command (with --shard {text} --out {folder}) "
             f"again with --resume")
    try:
        summary = read_json(folder / "summary.json")
    except FileNotFoundError:
        raise ParamError(f"shard {text} in {folder} has not finished (no summary.json); "
                         f"{again}") from None
    except (OSError, ValueError) as e:
        raise ParamError(f"{folder}/summary.json is unreadable ({e}); {again}") from None
    if not isinstance(summary, dict) or summary.get("shard") != sh:
        raise ParamError(f"{folder}/summary.json is not shard {text}'s; {again}")
    return summary


def _check_parts(parts: list[_Part], out: Path) -> None:
    """The parts are the N parts of one run from one commit, each once; ``out`` is none
    of them."""
    first = parts[0]
    whole = _whole_fingerprint(first)
    for p in parts[1:]:
        if _whole_fingerprint(p) != whole:
            diff = differing(first.spec, p.spec)
            shown = ", ".join(diff[:4]) + (", ..." if len(diff) > 4 else "")
            raise ParamError(f"{p.folder} and {first.folder} are shards of different runs "
                             f"(they differ in {shown or 'their fingerprints'}); merge the "
                             f"shards of one run")
        if p.shard.count != first.shard.count:
            raise ParamError(f"{p.folder} is part {p.shard} and {first.folder} part "
                             f"{first.shard}: the shards of one run share N")
        if p.commit != first.commit:
            raise ParamError(f"{p.folder} ran from commit {p.commit}, {first.folder} from "
                             f"{first.commit}; run every shard from one commit")
    seen: dict[int, Path] = {}
    for p in parts:
        if p.shard.index in seen:
            raise ParamError(f"shard {p.shard} is given twice ({seen[p.shard.index]} and "
                             f"{p.folder})")
        seen[p.shard.index] = p.folder
    n = first.shard.count
    missing = [i for i in range(1, n + 1) if i not in seen]
    if missing:
        shown = ", ".join(f"{i}/{n}" for i in missing[:8]) + (", ..." if len(missing) > 8
                                                              else "")
        raise ParamError(f"shard{'s' * (len(missing) > 1)} {shown} missing: a run in {n} "
                         f"shards merges all {n}, {len(parts)} given")
    target = os.path.realpath(out)
    for p in parts:
        if os.path.realpath(p.folder) == target:
            raise ParamError(f"--out {out} is one of the shards; merge into another folder")


def _whole_fingerprint(part: _Part) -> str:
    return whole_spec(part.spec)["fingerprint"]


def _experiment_config(folder: Path) -> tuple[Experiment, Any]:
    """The experiment and the config a shard recorded (as ``vbl report`` rebuilds them)."""
    try:
        exp, result, _ = load_run(folder, shard_ok=True)
    except EngineError as e:
        raise ParamError(str(e)) from None
    return exp, result.config


def _expected(plan: SweepPlan) -> list[tuple[int, int | str, int, int]]:
    """``(step, chunk, point, group)`` of every row of the whole run, in its order."""
    keys = []
    for g in plan.groups:
        for c in range(g.num_chunks):
            keys += [(g.step_offset + c + 1, c, p, g.index) for p in g.point_ids]
        if g.program.final is not None:
            keys += [(g.step_offset + g.num_chunks, "final", p, g.index) for p in g.point_ids]
    return keys


def _merged_rows(plan: SweepPlan, parts: list[_Part]) -> list[dict[str, Any]]:
    """The whole run's rows: per (step, chunk, point) the shards' per-seed values joined in
    seed order, their statistics computed again."""
    cells: dict[tuple, list[tuple[_Part, dict]]] = {}
    for part in parts:
        for row in read_metrics(part.folder / "metrics.jsonl"):
            key = (row.get("step"), row.get("chunk"), row.get("point"))
            cells.setdefault(key, []).append((part, row))
    rows = []
    for step, chunk, point, group in _expected(plan):
        got = sorted(cells.pop((step, chunk, point), []), key=lambda x: _seeds(x)[0])
        _check_cover(plan, parts, got, step, chunk, point)
        row = got[0][1]
        metrics = {k: seed_stats(np.concatenate([_per_seed(r, k, part) for part, r in got]))
                   for k in row.get("metrics") or {}}
        rows.append({"step": step, "group": group, "chunk": chunk, "point": point,
                     "values": row["values"], "metrics": metrics})
    if cells:
        (step, chunk, point), [(part, _), *_] = next(iter(cells.items()))
        raise ParamError(f"{part.folder}/metrics.jsonl has a row (step {step}, chunk {chunk}, "
                         f"point {point}) of no step of this run; rerun that shard with "
                         f"--overwrite")
    return rows


def _seeds(item: tuple[_Part, dict]) -> tuple[int, int]:
    part, row = item
    s = row.get("seeds")
    if not (isinstance(s, list) and len(s) == 2 and all(isinstance(x, int) for x in s)):
        raise ParamError(f"{part.folder}/metrics.jsonl has a row without its seeds; it is "
                         f"not a shard's metrics (restore it, or rerun that shard)")
    return s[0], s[1]


def _check_cover(plan: SweepPlan, parts: list[_Part], got: list[tuple[_Part, dict]],
                 step: int, chunk: int | str, point: int) -> None:
    """The rows ``got`` (sorted) hold each seed of ``point`` once."""
    at = 0
    for part, row in got:
        lo, hi = _seeds((part, row))
        if lo < at:
            raise ParamError(f"seed {lo} of point {point} at step {step} is in two shards "
                             f"({part.folder} and another); rerun that shard with "
                             f"--overwrite")
        if lo > at:
            break
        at = hi
    if at != plan.seeds:
        learner, total = point * plan.seeds + at, len(plan.points) * plan.seeds
        owner = next(p for p in parts if learner < p.shard.learner_range(total)[1]
                     and learner >= p.shard.learner_range(total)[0])
        raise ParamError(f"shard {owner.shard} in {owner.folder} lacks step {step} (chunk "
                         f"{chunk}) of point {point}, seed {at}: it did not finish; run its "
                         f"vbl run command again with --resume")


def _per_seed(row: dict, metric: str, part: _Part) -> np.ndarray:
    try:
        # JSON null stands for a value that was not finite; NumPy reads it as NaN
        return np.asarray(row["metrics"][metric]["per_seed"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise ParamError(f"{part.folder}/metrics.jsonl: a row at step {row.get('step')} lacks "
                         f"the per-seed values of {metric!r}; restore it, or rerun that "
                         f"shard") from None


def _write_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    path.unlink(missing_ok=True)
    MetricsLog(path).append(rows)


def _how(parts: list[_Part], plan: SweepPlan) -> dict[str, Any]:
    """The merged ``summary.json``'s account of how the shards ran."""
    parts = sorted(parts, key=lambda p: p.shard.index)
    each = [{"shard": str(p.shard), "folder": p.folder.name, "learners": p.summary.get("learners"),
             **{k: p.summary.get(k) for k in HOW}} for p in parts]
    num = lambda k: [x[k] for x in each if isinstance(x[k], int | float)]  # noqa: E731
    return {"wall_time_s": sum(num("wall_time_s")),
            "resumed_from_step": max(num("resumed_from_step"), default=0),
            "learners": plan.num_learners, "devices": sum(num("devices")),
            "processes": sum(num("processes")), "shards": each}
