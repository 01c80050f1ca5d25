"""Reports: an experiment's ``report.md`` in its run folder (``vbl run`` and ``vbl
reproduce``), the short table ``vbl run`` prints, and ``vbl reproduce``, which runs every
paper experiment and writes one ``report.md`` for all of them."""

from __future__ import annotations

import os
import time
import traceback
from pathlib import Path
from typing import Any

from vbl.engine.config import EngineError
from vbl.engine.experiment import Experiment, ReportSection, RunResult
from vbl.engine.registry import all_experiments, discover, import_errors
from vbl.engine.runfolder import record_files

__all__ = ["default_section", "default_jobs", "reproduce", "paper_experiments",
           "run_report", "headline_table", "TABLE_COLUMNS"]

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
