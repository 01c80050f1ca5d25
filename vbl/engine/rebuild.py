"""Reading finished run folders back: ``vbl report`` (the paper's numbers beside the
runs', with the command that rebuilds each run), a run's ``report.md`` built again, and
the command that reproduces a recorded config."""

from __future__ import annotations

import os
import shlex
from dataclasses import replace
from pathlib import Path
from typing import Any

from vbl.engine.config import (
    apply_overrides,
    config_to_dict,
    json_value,
    parse_assignment,
    parse_sweep,
)
from vbl.engine.errors import EngineError
from vbl.engine.experiment import Experiment, ReportSection, RunResult
from vbl.engine.plots import plot_names
from vbl.engine.registry import get
from vbl.engine.report import run_report, url_path
from vbl.engine.results import metric_arrays, read_json, read_metrics
from vbl.engine.runfolder import check_fingerprint, check_format
from vbl.engine.runner import defaults_spec, resolve
from vbl.params import ParamError

__all__ = ["load_run", "rerender", "run_command", "run_folders", "sibling_result",
           "results_table", "config_to_dict_values", "REPRODUCE_MANIFEST"]

REPRODUCE_MANIFEST = "reproduce.json"
"""What ``vbl reproduce`` ran, in order: per run its experiment, preset, folder, status, wall
time and peak memory; the commit, machine and load of the whole run."""


def rerender(folder: str | Path) -> ReportSection:
    """Build a finished run folder's report again (its curves from ``metrics.jsonl``, its
    engine figures as they are) and write its ``report.md``; returns the section."""
    exp, res, _ = load_run(folder)
    curves, _ = metric_arrays(read_metrics(Path(folder) / "metrics.jsonl"), len(res.points))
    figures = [p for p in (Path(folder) / n for n in plot_names(curves)) if p.is_file()]
    res = replace(res, curves=curves, figures=figures)
    return run_report(exp, res)[0]


def load_run(folder: str | Path, shard_ok: bool = False
             ) -> tuple[Experiment, RunResult, dict[str, Any]]:
    """``(experiment, RunResult, config.json)`` of a finished run folder. The result is
    rebuilt from ``config.json`` and ``summary.json``: ``final`` holds the per-seed values
    (``[points, seeds]``), ``curves`` is empty, ``config`` is the experiment's default
    config with the folder's recorded values. A folder of another run-folder format, or
    one that records parameters the experiment does not have, is an EngineError, and so is
    one shard of a run (``vbl run --shard``) unless ``shard_ok`` (``vbl merge`` reads them)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise EngineError(f"{folder} is not a run folder (no such folder)")
    missing = [n for n in ("config.json", "summary.json") if not (folder / n).is_file()]
    if missing:
        raise EngineError(f"{folder} is not a finished run folder (no {' or '.join(missing)})")
    try:
        spec, summary = read_json(folder / "config.json"), read_json(folder / "summary.json")
    except ValueError as e:
        raise EngineError(f"{folder}: unreadable config.json or summary.json: {e}") from e
    if not isinstance(spec, dict) or "experiment" not in spec or "config" not in spec:
        raise EngineError(f"{folder}/config.json is not a vbl run's config")
    check_format(spec, folder)
    if "shard" in spec and not shard_ok:
        part = spec["shard"]
        raise EngineError(f"{folder} is part {part.get('index')}/{part.get('count')} of a "
                          "sharded run: merge its parts first (vbl merge FOLDER... --out X)")
    exp = get(spec["experiment"])
    check_fingerprint(spec, folder, _originals(spec, summary))
    config = _recorded_config(exp, spec, folder)
    points = summary.get("points", [])
    final: dict[str, Any] = {}
    for i, entry in enumerate(points):
        for k, st in entry.get("final", {}).items():
            if isinstance(st, dict) and "per_seed" in st:
                final.setdefault(k, [None] * len(points))[i] = st["per_seed"]
    final = {k: v for k, v in final.items() if all(x is not None for x in v)}
    result = RunResult(exp.name, folder, config, dict(spec.get("sweep", {})),
                       [dict(e.get("values", {})) for e in points] or [{}],
                       int(spec.get("seeds", 1)), {}, final, summary,
                       sorted(folder.glob("*.png")), dict(summary.get("result") or {}))
    return exp, result, spec


def _originals(spec: dict[str, Any], summary: Any) -> list[dict[str, Any]]:
    """What a run folder's ``config.json`` is compared with when it no longer matches its
    fingerprint: the experiment's defaults with the recorded ``--quick`` and preset
    (:func:`~vbl.engine.runner.defaults_spec`), and the recorded values with the seeds and
    sweep of ``summary.json``."""
    out = defaults_spec(spec)
    if isinstance(summary, dict):
        got = {k: summary[k] for k in ("seeds", "sweep") if k in summary}
        if got:
            out.append({**{k: v for k, v in spec.items() if k != "fingerprint"}, **got})
    return out


def _recorded_config(exp: Experiment, spec: dict[str, Any], folder: Path) -> Any:

    defaults = config_to_dict(exp.default_config)
    unknown = sorted(k for k in spec["config"] if k not in defaults)
    if unknown:
        raise EngineError(f"{folder} records parameters {exp.name} does not have "
                          f"({', '.join(unknown[:4])}{', ...' if len(unknown) > 4 else ''}); "
                          f"rerun it with today's code")
    sets = {k: tuple(v) if isinstance(v, list) else v
            for k, v in spec["config"].items() if defaults.get(k) != v}
    try:
        return apply_overrides(exp.default_config, sets)
    except ParamError as e:
        raise EngineError(f"{folder}: its config no longer validates: {e}") from e


def config_to_dict_values(values: Any) -> dict[str, Any]:
    """``{path: value}`` with JSON values (tuples as lists), as ``config.json`` holds them."""
    return {k: json_value(v) for k, v in dict(values).items()}


def _cli_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list | tuple):
        items = [_cli_value(x) for x in v]
        numeric = all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        return ",".join(items) if numeric and len(items) > 1 else "(" + ",".join(items) + ")"
    return str(v)


def run_command(exp: Experiment, spec: dict[str, Any]) -> str:
    """The ``vbl run`` command that regenerates a run folder, from its ``config.json``
    (``spec``): ``--quick`` and ``--preset`` as recorded, ``--seeds``/``--seed`` when they
    differ from the experiment's, ``--sweep`` for a sweep other than the default one,
    ``--set`` for every other recorded value that differs from what those give. The
    command is checked: resolving it gives the folder's recorded values."""
    rec = config_to_dict_values(spec["config"])
    quick, preset = bool(spec.get("quick")), spec.get("preset")
    seeds, base_seed = int(spec.get("seeds", exp.seeds)), int(spec.get("base_seed", 0))
    sweep = {k: list(v) for k, v in spec.get("sweep", {}).items()}
    texts_sweep, texts_set = _sweep_and_set_texts(exp, rec, sweep, quick, preset)
    args = _run_flags(exp, quick, preset, seeds, base_seed)
    args += [a for t in texts_sweep for a in ("--sweep", t)]
    args += [a for t in texts_set for a in ("--set", t)]
    _check_command(exp, rec, sweep, texts_sweep, texts_set,
                   seeds if "--seeds" in args else None, seeds, base_seed, quick, preset)
    return " ".join(shlex.quote(a) for a in args)


def _run_flags(exp: Experiment, quick: bool, preset: str | None, seeds: int,
               base_seed: int) -> list[str]:
    """``vbl run NAME`` with ``--quick``, ``--preset``, and ``--seeds`` / ``--seed`` where
    they differ from the experiment's (quick) defaults."""
    args = ["vbl", "run", exp.name] + (["--quick"] if quick else [])
    args += ["--preset", preset] if preset else []
    if seeds != ((exp.quick_seeds or exp.seeds) if quick else exp.seeds):
        args += ["--seeds", str(seeds)]
    if base_seed:
        args += ["--seed", str(base_seed)]
    return args


def _sweep_and_set_texts(exp: Experiment, rec: dict[str, Any], sweep: dict[str, list],
                         quick: bool, preset: str | None) -> tuple[list[str], list[str]]:
    """``(--sweep texts, --set texts)`` of a recorded config ``rec`` and ``sweep``: a
    ``--sweep`` per swept path whose values differ from the default sweep's (the one
    ``--quick`` gives, under it), a ``--set`` per default-swept path the run did not sweep,
    and per other value that differs from what ``--quick`` and the preset give."""
    default_sweep = {k: config_to_dict_values({"v": list(v)})["v"] for k, v in
                     resolve(exp, quick=quick, preset=preset)[1].items()}  # --quick's own
    base_cfg, *_ = resolve(exp, None, sweep, None, 0, quick, preset)
    base = config_to_dict(base_cfg)
    texts_sweep = [f"{k}={','.join(_cli_value(x) for x in v)}" for k, v in sweep.items()
                   if default_sweep.get(k) != v]
    texts_set = [f"{k}={_cli_value(rec[k])}" for k in default_sweep if k not in sweep]
    texts_set += [f"{k}={_cli_value(v)}" for k, v in rec.items()
                  if k not in sweep and k not in default_sweep and base.get(k) != v]
    return texts_sweep, texts_set


def _check_command(exp: Experiment, rec: dict[str, Any], sweep: dict[str, list],
                   texts_sweep: list[str], texts_set: list[str], seeds_arg: int | None,
                   seeds: int, base_seed: int, quick: bool, preset: str | None) -> None:
    """Resolve the command's ``--sweep`` and ``--set`` texts (with ``seeds_arg`` as
    ``--seeds``) as ``vbl run`` would; an EngineError unless that gives the recorded
    values ``rec``, ``sweep`` and ``seeds``."""
    cfg = exp.default_config
    sets = dict(parse_assignment(t, cfg) for t in texts_set)
    sw = dict(parse_sweep(t, cfg) for t in texts_sweep)
    _, full_sweep, got_seeds, got = resolve(exp, sets, sw, seeds_arg, base_seed, quick, preset)
    # a swept path's recorded base value never reaches a learner: the sweep replaces it
    bad = [k for k, v in rec.items() if k not in sweep and got["config"].get(k) != v]
    if bad or got_seeds != seeds or config_to_dict_values(full_sweep) != sweep:
        what = (f"{bad[0]} would be {got['config'].get(bad[0])!r}, not {rec[bad[0]]!r}"
                if bad else "the sweep or seeds differ")
        raise EngineError(f"cannot rebuild the command of a {exp.name} run: {what}")


def sibling_result(result: RunResult, folder_name: str) -> RunResult | None:
    """The finished run folder ``folder_name`` beside ``result``'s (as ``vbl reproduce``
    lays out its runs) as a RunResult; None when there is none or it cannot be read."""
    folder = Path(result.out_dir).parent / folder_name
    if not (folder / "summary.json").is_file():
        return None
    try:
        return load_run(folder)[1]
    except EngineError:
        return None


def run_folders(folders: list[str | Path]) -> list[Path]:
    """Run folders in order, a ``vbl reproduce`` folder (one with ``reproduce.json``)
    replaced by its runs in the order it ran them."""
    out = []
    for f in map(Path, folders):
        manifest = f / REPRODUCE_MANIFEST
        if manifest.is_file():
            out += [f / r["folder"] for r in read_json(manifest)["runs"]]
        else:
            out.append(f)
    return out


def results_table(folders: list[str | Path], link_base: str | Path | None = None,
                  load=load_run) -> str:
    """``vbl report``: one Markdown table over run folders (a ``vbl reproduce`` folder
    stands for its runs), a row per paper number (the experiments'
    :attr:`~vbl.engine.Experiment.paper_rows`) with vbl's mean and 95 % interval, the
    seeds, a link to the run folder and the command that regenerates it (shown on the first
    row of each run). Links are relative to ``link_base`` (default: the current folder);
    ``load(folder) -> (experiment, RunResult, config.json)`` reads a run (default
    :func:`load_run`; :func:`vbl.engine.seed_subsets.first_seeds` for fewer seeds)."""
    base = Path(link_base if link_base is not None else ".").absolute()
    lines = ["| paper result | paper | vbl (mean, 95 % CI) | seeds | run | command |",
             "|---|---|---|---|---|---|"]
    for folder in run_folders(folders):
        exp, result, spec = load(folder)
        if exp.paper_rows is None:
            raise EngineError(f"experiment {exp.name} declares no paper rows "
                              f"(Experiment.paper_rows); {folder} cannot be reported")
        command = run_command(exp, spec)
        rows = exp.paper_rows(result)
        rel = url_path(os.path.relpath(Path(folder).absolute(), base))
        name = Path(folder).name.replace("[", "\\[").replace("]", "\\]")
        link = (f"[{name}]({rel}/report.md)" if (Path(folder) / "report.md")
                .is_file() else f"[{name}]({rel}/)")
        for i, r in enumerate(rows):
            first = i == 0
            lines.append(f"| {r.result} | {r.paper} | {r.ours} | {result.seeds if first else ''}"
                         f" | {link if first else ''} | {f'`{command}`' if first else ''} |")
    return "\n".join(lines) + "\n"
