"""Reports: an experiment's ``report.md`` in its run folder (``vbl run`` and ``vbl
reproduce``), the short table ``vbl run`` prints, ``vbl reproduce``, which runs every
paper experiment and writes one ``report.md`` for all of them, and ``vbl report``, which
reads committed run folders into one table of the paper's numbers beside vbl's."""

from __future__ import annotations

import math
import os
import shlex
import time
import traceback
from pathlib import Path
from typing import Any

from vbl.engine.config import EngineError, config_to_dict
from vbl.engine.experiment import Experiment, ReportSection, RunResult
from vbl.engine.registry import all_experiments, discover, import_errors
from vbl.engine.runfolder import record_files
from vbl.stats import mean_ci95, t_quantile_975

__all__ = ["default_section", "default_jobs", "reproduce", "paper_experiments",
           "run_report", "headline_table", "TABLE_COLUMNS", "load_run", "run_command",
           "stat_cell", "seeds_cell", "results_table"]

TABLE_COLUMNS = 100  #: the width ``vbl run``'s terminal table keeps to


def _fmt(st: dict[str, Any]) -> str:
    m, ci = st.get("mean"), st.get("ci95")
    if isinstance(m, int | float) and isinstance(ci, int | float):
        return f"{m:.4g} ± {ci:.2g}"
    return str(m)


def default_section(result: RunResult) -> ReportSection:
    """A table of every sweep point's scalar last-chunk and final metrics (mean ± 95% CI);
    array-valued metrics (e.g. a learned map) stay in ``summary.json`` only."""
    lines = []
    for entry in result.summary.get("points", []):
        label = ", ".join(f"{k}={v}" for k, v in entry["values"].items()) or "default config"
        stats = {**{f"{k} (last chunk)": v for k, v in entry.get("last_chunk", {}).items()},
                 **{f"{k} (final)": v for k, v in entry.get("final", {}).items()}}
        stats = {k: v for k, v in stats.items() if not isinstance(v.get("mean"), list)}
        if not lines:
            lines += ["| point | " + " | ".join(stats) + " |", "|---" * (len(stats) + 1) + "|"]
        lines.append(f"| {label} | " + " | ".join(_fmt(v) for v in stats.values()) + " |")
    if not lines and "result" in result.summary:
        lines = ["```", str(result.summary["result"]), "```"]
    return ReportSection("\n".join(lines), tuple(result.figures))


def paper_experiments() -> dict[str, Experiment]:
    discover()
    return {n: e for n, e in all_experiments().items() if e.paper_result}


def _figure_path(f: str | Path, out_dir: Path) -> Path:
    """A report's figure path, absolute. A relative path is taken from the working directory
    when it exists there (experiments usually return run_dir / name with a relative
    run_dir), else from the run folder."""
    p = Path(f)
    if not p.is_absolute() and not p.exists():
        p = Path(out_dir) / p
    return p.absolute()


def run_report(exp: Experiment, result: RunResult) -> tuple[ReportSection, Path]:
    """Build the experiment's report section (its ``report``, else :func:`default_section`)
    and write it with its figures to ``<run folder>/report.md``. Figures the report writes
    and ``report.md`` are recorded as the run's files (``--overwrite`` replaces them).
    Returns ``(section with absolute figure paths, report.md)``."""
    out_dir = Path(result.out_dir)
    before = {p.name for p in out_dir.iterdir()}
    try:
        section = exp.report(result) if exp.report is not None else default_section(result)
        figs = tuple(_figure_path(f, out_dir) for f in section.figures)
        links = [f"![{f.stem}]({os.path.relpath(f, out_dir.absolute())})" for f in figs]
        path = out_dir / "report.md"
        path.write_text("\n".join([f"# {exp.name}", "", exp.description, "",
                                    section.markdown, "", *(f + "\n" for f in links)]) + "\n")
    finally:
        record_files(out_dir, {p.name for p in out_dir.iterdir()} - before)
    return ReportSection(section.markdown, figs), path


def _cell(st: dict[str, Any]) -> str:
    m, ci = st.get("mean"), st.get("ci95")
    if not isinstance(m, int | float):
        return str(m)
    if not isinstance(ci, int | float) or ci != ci:
        return f"{m:.3g}"
    return f"{m:.3g} ± {ci:.2g}"


def headline_table(result: RunResult, exp: Experiment | None = None,
                   width: int = TABLE_COLUMNS) -> str:
    """The short table ``vbl run`` prints: one row per sweep point, the experiment's
    :attr:`~vbl.engine.Experiment.headline` metrics (mean ± 95 % interval over seeds; a
    ``final`` metric, else the last chunk's), or by default the scalar ``final`` metrics then
    the last chunk's, as many as fit ``width`` columns. The full table is in
    ``summary.json``."""
    points = result.summary.get("points", [])
    if not points:
        res = result.summary.get("result")
        if res is None:
            return ""
        keys = list(res) if isinstance(res, dict) else []
        text = "result keys: " + ", ".join(keys) if keys else "result: " + str(res)
        return text if len(text) <= width else text[:width - 3] + "..."

    def scalar(st):
        return isinstance(st, dict) and isinstance(st.get("mean"), int | float)

    def lookup(entry, name):
        st = entry.get("final", {}).get(name)
        return st if st is not None else entry.get("last_chunk", {}).get(name)

    first = points[0]
    if exp is not None and exp.headline:
        names = [n for n in exp.headline if scalar(lookup(first, n))]
    else:
        names = [n for n, st in first.get("final", {}).items() if scalar(st)]
        names += [n for n, st in first.get("last_chunk", {}).items()
                  if scalar(st) and n not in names and n != "episodes"]
    full = [", ".join(f"{k}={v}" for k, v in e["values"].items()) or "default config"
            for e in points]
    short = [", ".join(f"{k.rsplit('.', 1)[-1]}={v}" for k, v in e["values"].items())
             or "default config" for e in points]
    labels = full if max(map(len, full)) <= 40 else short
    cols = [("point", labels)]
    used = max(len("point"), *map(len, labels))
    left = []
    for n in names:
        cells = [_cell(lookup(e, n) or {}) for e in points]
        w = max(len(n), *map(len, cells))
        if used + 3 + w > width:
            left.append(n)
            continue
        cols.append((n, cells))
        used += 3 + w
    widths = [max(len(h), *map(len, c)) for h, c in cols]
    fmt = lambda row: " | ".join(  # noqa: E731
        x.ljust(w) for x, w in zip(row, widths, strict=True)).rstrip()
    lines = [fmt([h for h, _ in cols]), "-+-".join("-" * w for w in widths)]
    lines += [fmt([c[i] for _, c in cols]) for i in range(len(points))]
    seeds = result.summary.get("seeds", result.seeds)
    note = f"mean ± 95% interval over {seeds} seeds"
    if left:
        note += f"; {len(left)} more metric{'s' * (len(left) != 1)} in summary.json"
    return "\n".join(lines + [note])


def default_jobs(n_experiments: int) -> int:
    """Worker processes for ``vbl reproduce``: one per CPU core, at most one per experiment.

    A quick run is dominated by XLA compilation, which uses one core per program, so
    experiments in separate processes use every core while they compile.
    """
    return max(1, min(os.cpu_count() or 1, n_experiments))


def _run_one(name: str, out: Path, quick: bool, quiet: bool | None, resume: bool,
             overwrite: bool, exp: Experiment | None = None) -> dict[str, Any]:
    """Run one paper experiment and build its report section; never raises.

    In a worker process ``exp`` is None and the experiment is looked up in the registry
    (the worker imports the experiment scripts itself). Returns a picklable dict.
    """
    from vbl.engine.runner import run_experiment

    t0 = time.perf_counter()
    result = None
    try:
        if exp is None:
            exp = paper_experiments()[name]
        result = run_experiment(exp, out=out / name, quick=quick, quiet=quiet,
                                resume=resume and (out / name).exists(), overwrite=overwrite)
        section, _ = run_report(exp, result)
        status = "ok"
    except Exception as e:  # noqa: BLE001 - report and continue with the others
        status = f"failed: {type(e).__name__}: {e}"
        section = ReportSection("**failed**\n\n```\n" + "".join(
            traceback.format_exception(type(e), e, e.__traceback__))[-3000:] + "```")
    figs = [str(_figure_path(f, result.out_dir if result is not None else Path.cwd()))
            for f in section.figures]
    return dict(status=status, markdown=section.markdown, figures=figs,
                seconds=time.perf_counter() - t0)


def _run_chain(names: list[str], out: Path, quick: bool, resume: bool, overwrite: bool
               ) -> dict[str, dict]:
    """Worker task: run experiments one after the other (one :attr:`Experiment.group`)."""
    from vbl.engine.errors import quiet_xla_log
    from vbl.engine.jax_setup import use_compilation_cache

    quiet_xla_log()
    use_compilation_cache()
    return {n: _run_one(n, out, quick, True, resume, overwrite) for n in names}


def _chains(exps: dict[str, Experiment]) -> list[list[str]]:
    """Experiments grouped by :attr:`Experiment.group` (registry order inside a group),
    costliest chain first."""
    chains: dict[str, list[str]] = {}
    for n, e in exps.items():
        chains.setdefault(e.group if e.group is not None else f"\0{n}", []).append(n)
    return sorted(chains.values(), key=lambda c: -sum(exps[n].cost for n in c))


def _run_parallel(exps: dict[str, Experiment], jobs: int, out: Path, quick: bool,
                  resume: bool, overwrite: bool, quiet: bool | None) -> dict[str, dict]:
    """Run experiments in ``jobs`` spawned worker processes, costliest chain first."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    done: dict[str, dict] = {}
    ctx = multiprocessing.get_context("spawn")  # jax is not fork-safe
    with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
        futures = {pool.submit(_run_chain, c, out, quick, resume, overwrite): c
                   for c in _chains(exps)}
        for fut in as_completed(futures):
            try:
                results = fut.result()
            except Exception as e:  # noqa: BLE001 - a worker died (killed, out of memory)
                results = {n: dict(status=f"failed: worker process died: {e!r}",
                                   markdown="**failed** (worker process died)", figures=[],
                                   seconds=float("nan")) for n in futures[fut]}
            for name, r in results.items():
                done[name] = r
                if not quiet:
                    print(f"[{len(done)}/{len(exps)}] {name}: {r['status'].splitlines()[0]}"
                          f" ({r['seconds']:.0f} s)", flush=True)
    return done


def reproduce(out: Path, *, quick: bool, quiet: bool | None, resume: bool = False,
              overwrite: bool = False, names: list[str] | None = None,
              jobs: int | None = 1) -> tuple[Path, bool]:
    """Run the paper experiments into ``out/<name>/`` and write ``out/report.md``.

    ``jobs``: worker processes (None: :func:`default_jobs`; 1: in this process, in
    registry order). With ``jobs > 1`` every experiment runs quietly in a spawned process
    that imports the experiment scripts itself, so only discoverable experiments (scripts
    in the experiments folders) can run there. Results do not depend on ``jobs``.
    Returns ``(report path, all succeeded)``. A failing experiment is reported and the
    others still run.
    """
    from vbl.engine.runfolder import check_new_folder

    exps = paper_experiments()
    if names:
        bad = [n for n in names if n not in exps]
        if bad:
            raise EngineError(f"unknown paper experiment(s) {bad}; valid: {sorted(exps)}")
        exps = {n: exps[n] for n in names}
    out = Path(out)
    if not (resume or overwrite):
        check_new_folder(out, resume=False, overwrite=False)  # raises clearly
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise EngineError(f"cannot write to output folder {out}: {e.strerror or e}") from e
    jobs = default_jobs(len(exps)) if jobs is None else max(1, min(int(jobs), len(exps) or 1))
    t_start = time.perf_counter()
    if jobs > 1:
        done = _run_parallel(exps, jobs, out, quick, resume, overwrite, quiet)
    else:
        done = {n: _run_one(n, out, quick, quiet, resume, overwrite, exp=e)
                for n, e in exps.items()}
    wall = time.perf_counter() - t_start
    parts = [f"# vbl reproduction report{' (--quick)' if quick else ''}", "",
             f"Generated {time.strftime('%Y-%m-%d %H:%M:%S')} in {wall:.0f} s wall "
             f"({jobs} worker process{'es' if jobs > 1 else ''}). Each section puts our "
             "numbers beside the paper's; intervals are 95% confidence intervals over seeds.",
             ""]
    ok = True
    rows = []
    sections = []
    for name, exp in exps.items():
        r = done[name]
        ok &= r["status"] == "ok"
        rows.append(f"| {name} | {exp.description} | {r['status'].splitlines()[0]} | "
                    f"{r['seconds']:.1f} |")
        figs = [f"![{Path(f).stem}]({os.path.relpath(f, out.absolute())})"
                for f in r["figures"]]
        sections += [f"## {name}", "", exp.description, "", r["markdown"], "",
                     *(f + "\n" for f in figs), ""]
    for path, err in import_errors().items():
        rows.append(f"| {Path(path).stem} | (script failed to import) | failed: {err} | |")
        ok = False
    parts += ["| experiment | what | status | time (s) |", "|---|---|---|---|", *rows, "",
              *sections]
    report = out / "report.md"
    report.write_text("\n".join(parts) + "\n")
    return report, ok


# ---------------------------------------------------------------- vbl report


def stat_cell(st: dict[str, Any], scale: float = 1.0, fmt: str = ".3g",
              n: int | None = None) -> str:
    """``"mean ± half-width"`` of a summary statistic ``{"mean", "ci95"}`` (the 95 %
    Student t interval over seeds), scaled by ``scale``. With ``n``, the interval is
    computed from ``st["std"]``, a population std (ddof 0) over ``n`` values (the
    identification tables store no interval)."""
    m = st.get("mean")
    if not isinstance(m, int | float):
        return "-"
    if n is not None:
        sd = st.get("std")
        ci = (t_quantile_975(n - 1) * sd / math.sqrt(n - 1)
              if isinstance(sd, int | float) and n > 1 else None)
    else:
        ci = st.get("ci95")
    if not isinstance(ci, int | float) or ci != ci:
        return format(m * scale, fmt)
    return f"{format(m * scale, fmt)} ± {format(ci * scale, fmt)}"


def seeds_cell(values: Any, scale: float = 1.0, fmt: str = ".3g") -> str:
    """``"mean ± half-width"`` of per-seed values (95 % Student t interval of the mean)."""
    import numpy as np

    m, half = mean_ci95(np.asarray(values, np.float64).ravel() * scale)
    if half != half:
        return format(m, fmt)
    return f"{format(m, fmt)} ± {format(half, fmt)}"


def load_run(folder: str | Path) -> tuple[Experiment, RunResult, dict[str, Any]]:
    """``(experiment, RunResult, config.json)`` of a finished run folder. The result is
    rebuilt from ``config.json`` and ``summary.json``: ``final`` holds the per-seed values
    (``[points, seeds]``), ``curves`` is empty, ``config`` is the experiment's default
    config with the folder's recorded values."""
    from vbl.engine.registry import get
    from vbl.engine.results import read_json

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
    exp = get(spec["experiment"])
    config = _recorded_config(exp, spec, folder)
    points = summary.get("points", [])
    renamed = dict(exp.renamed_metrics)
    final: dict[str, Any] = {}
    for i, entry in enumerate(points):
        for k, st in entry.get("final", {}).items():
            if isinstance(st, dict) and "per_seed" in st:
                final.setdefault(renamed.get(k, k), [None] * len(points))[i] = st["per_seed"]
    final = {k: v for k, v in final.items() if all(x is not None for x in v)}
    result = RunResult(exp.name, folder, config, _renamed_keys(exp, spec.get("sweep", {})),
                       [_renamed_keys(exp, e.get("values", {})) for e in points] or [{}],
                       int(spec.get("seeds", 1)), {}, final, summary,
                       sorted(folder.glob("*.png")), dict(summary.get("result") or {}))
    return exp, result, spec


def _renamed_keys(exp: Experiment, values: dict[str, Any]) -> dict[str, Any]:
    """``{path: value}`` of a run folder (its sweep, a point's values) under today's paths
    (:meth:`Experiment.renamed`)."""
    return {exp.renamed(k): v for k, v in dict(values).items()}


def _recorded_config(exp: Experiment, spec: dict[str, Any], folder: Path) -> Any:
    from vbl.engine.config import apply_overrides
    from vbl.params import ParamError

    defaults = config_to_dict(exp.default_config)
    sets = {k: tuple(v) if isinstance(v, list) else v
            for k, v in _recorded_values(exp, spec).items() if defaults.get(k) != v}
    try:
        return apply_overrides(exp.default_config, sets)
    except ParamError as e:
        raise EngineError(f"{folder}: its config no longer validates: {e}") from e


def _in_todays_terms(exp: Experiment, spec: dict[str, Any]) -> dict[str, Any]:
    """The folder's recorded ``{path: value}`` after :attr:`Experiment.migrate` and
    :attr:`Experiment.renamed_params` (paths the experiment no longer has stay)."""
    recorded = dict(spec["config"])
    if exp.migrate is not None:
        recorded = exp.migrate(recorded)
    out = {}
    for path, value in recorded.items():
        new = exp.renamed(path)
        if new == path or new not in recorded:  # a recorded current path wins
            out[new] = value
    return out


def _recorded_values(exp: Experiment, spec: dict[str, Any]) -> dict[str, Any]:
    """The folder's parameter values that the experiment still has, with
    :attr:`Experiment.legacy_values` for parameters it does not record."""
    current = config_to_dict(exp.default_config)
    legacy = config_to_dict_values(exp.legacy_values)
    recorded = _in_todays_terms(exp, spec)
    rec = {k: v for k, v in recorded.items() if k in current}
    return {**{k: v for k, v in legacy.items() if k not in recorded}, **rec}


def config_to_dict_values(values: Any) -> dict[str, Any]:
    """``{path: value}`` with JSON values (tuples as lists), as ``config.json`` holds them."""
    from vbl.engine.config import _jsonable

    return {k: _jsonable(v) for k, v in dict(values).items()}


def _cli_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list | tuple):
        items = [_cli_value(x) for x in v]
        numeric = all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        return ",".join(items) if numeric and len(items) > 1 else "(" + ",".join(items) + ")"
    return str(v)


def _matching_preset(exp: Experiment, rec: dict[str, Any], base: dict[str, Any],
                     sweep: dict[str, Any]) -> str | None:
    """The preset with the most values that the folder records, all of them (paths it
    sweeps aside), one of them not the default; None if there is none."""
    best, size = None, 0
    for name, values in exp.presets.items():
        vals = {k: v for k, v in config_to_dict_values(values).items() if k not in sweep}
        if (vals and all(rec.get(k) == v for k, v in vals.items())
                and any(base.get(k) != v for k, v in vals.items()) and len(vals) > size):
            best, size = name, len(vals)
    return best


def run_command(exp: Experiment, spec: dict[str, Any]) -> tuple[str, list[str]]:
    """The ``vbl run`` command that regenerates a run folder, rebuilt from its
    ``config.json`` (``spec``): ``--quick`` when the folder holds every quick override
    (for an experiment without any: its quick number of seeds),
    ``--seeds``/``--seed`` when they differ from the experiment's, ``--preset`` for the
    largest preset whose values the folder holds, ``--sweep`` for a sweep other than the
    default one, ``--set`` for every other recorded value that differs from the default.
    Returns ``(command, unrecorded)``: the parameters the folder does not record (and
    :attr:`Experiment.legacy_values` does not give), for which the command takes today's
    default. The command is checked: resolving it gives the folder's recorded values."""
    from vbl.engine.config import parse_assignment, parse_sweep
    from vbl.engine.runner import resolve

    rec = _recorded_values(exp, spec)
    seeds, base_seed = int(spec.get("seeds", exp.seeds)), int(spec.get("base_seed", 0))
    sweep = {k: list(v) for k, v in _renamed_keys(exp, spec.get("sweep", {})).items()}
    quick_vals = config_to_dict_values(exp.quick)
    quick_seeds = exp.quick_seeds or exp.seeds
    # --quick: every quick override recorded (without any, the quick number of seeds)
    quick = (all(rec.get(k) == v for k, v in quick_vals.items()) if quick_vals
             else quick_seeds != exp.seeds and seeds == quick_seeds)
    base = config_to_dict(exp.default_config)
    base.update(quick_vals if quick else {})
    args = ["vbl", "run", exp.name] + (["--quick"] if quick else [])
    if seeds != (quick_seeds if quick else exp.seeds):
        args += ["--seeds", str(seeds)]
    if base_seed:
        args += ["--seed", str(base_seed)]
    default_sweep = {k: config_to_dict_values({"v": list(v)})["v"] for k, v in exp.sweep.items()}
    texts_sweep = [f"{k}={','.join(_cli_value(x) for x in v)}" for k, v in sweep.items()
                   if default_sweep.get(k) != v]
    texts_set = [f"{k}={_cli_value(rec[k])}" for k in default_sweep if k not in sweep]
    texts_set += [f"{k}={_cli_value(v)}" for k, v in rec.items()
                  if k not in sweep and k not in default_sweep and base.get(k) != v]
    preset = _matching_preset(exp, rec, base, sweep)
    if preset:
        args += ["--preset", preset]
        texts_set = [t for t in texts_set if t.split("=", 1)[0] not in exp.presets[preset]]
    for t in texts_sweep:
        args += ["--sweep", t]
    for t in texts_set:
        args += ["--set", t]
    # check: the command resolves to the folder's recorded values
    cfg = exp.default_config
    sets = exp.preset(preset, sweep)
    sets.update(parse_assignment(t, cfg) for t in texts_set)
    sw = dict(parse_sweep(t, cfg) for t in texts_sweep)
    _, full_sweep, got_seeds, got = resolve(exp, sets, sw, seeds if "--seeds" in args else None,
                                            base_seed, quick)
    # a swept path's recorded base value never reaches a learner: the sweep replaces it
    bad = [k for k, v in rec.items() if k not in sweep and got["config"].get(k) != v]
    got_sweep = config_to_dict_values(full_sweep)
    if bad or got_seeds != seeds or got_sweep != config_to_dict_values(sweep):
        what = (f"{bad[0]} would be {got['config'].get(bad[0])!r}, not {rec[bad[0]]!r}"
                if bad else "the sweep or seeds differ")
        raise EngineError(f"cannot rebuild the command of a {exp.name} run: {what}")
    unrecorded = sorted(k for k in base if k not in rec)
    return " ".join(shlex.quote(a) for a in args), unrecorded


def results_table(folders: list[str | Path], link_base: str | Path | None = None) -> str:
    """``vbl report``: one Markdown table over run folders, a row per paper number (the
    experiments' :attr:`~vbl.engine.Experiment.paper_rows`) with vbl's mean ± 95 %
    interval, the seeds, a link to the run folder and the command that regenerates it
    (shown on the first row of each run). Links are relative to ``link_base`` (default:
    the current folder)."""
    base = Path(link_base if link_base is not None else ".").absolute()
    lines = ["| paper result | paper | vbl (mean ± 95 % CI) | seeds | run | command |",
             "|---|---|---|---|---|---|"]
    notes = []
    for folder in folders:
        exp, result, spec = load_run(folder)
        if exp.paper_rows is None:
            raise EngineError(f"experiment {exp.name} declares no paper rows "
                              f"(Experiment.paper_rows); {folder} cannot be reported")
        command, unrecorded = run_command(exp, spec)
        rows = exp.paper_rows(result)
        rel = Path(os.path.relpath(Path(folder).absolute(), base)).as_posix()
        link = (f"[{Path(folder).name}]({rel}/report.md)" if (Path(folder) / "report.md")
                .is_file() else f"[{Path(folder).name}]({rel}/)")
        for i, r in enumerate(rows):
            first = i == 0
            lines.append(f"| {r.result} | {r.paper} | {r.ours} | {result.seeds if first else ''}"
                         f" | {link if first else ''} | {f'`{command}`' if first else ''} |")
        if unrecorded:
            notes.append(f"{Path(folder).name} does not record {', '.join(unrecorded)}: its "
                         f"command takes today's default for these.")
        current = config_to_dict(exp.default_config)
        removed = {k: v for k, v in _in_todays_terms(exp, spec).items() if k not in current
                   and k not in exp.renamed_params and not exp.removed_as_today(k, v)}
        if removed:
            notes.append(f"{Path(folder).name} ran with options vbl no longer has ("
                         + ", ".join(f"{k}={v}" for k, v in removed.items())
                         + "): its command runs today's code.")
    return "\n".join(lines + ([""] + notes if notes else [])) + "\n"
