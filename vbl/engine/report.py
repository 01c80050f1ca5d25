"""Reports: an experiment's ``report.md`` in its run folder (``vbl run`` and ``vbl
reproduce``), the short table ``vbl run`` prints, ``vbl reproduce``, which runs every
paper experiment and writes one ``report.md`` for all of them, and ``vbl report``, which
reads committed run folders into one table of the paper's numbers beside vbl's."""

from __future__ import annotations

import contextlib
import json
import math
import os
import shlex
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from vbl.engine.config import EngineError, config_to_dict
from vbl.engine.experiment import Experiment, ReportSection, RunResult
from vbl.engine.machine import git_commit, load_average, machine_description
from vbl.engine.plots import is_rate
from vbl.engine.registry import all_experiments, discover, import_errors
from vbl.engine.runfolder import record_files
from vbl.stats import mean_ci95, t_quantile_975

__all__ = ["default_section", "default_jobs", "reproduce", "reproduce_jobs", "Job",
           "paper_experiments", "run_report", "headline_table", "TABLE_COLUMNS", "load_run",
           "run_command", "run_folders", "sibling_result", "stat_cell", "seeds_cell",
           "rate_cell", "RATE", "claim", "results_table", "REPRODUCE_MANIFEST"]

TABLE_COLUMNS = 100  #: the width ``vbl run``'s terminal table keeps to




def default_section(result: RunResult) -> ReportSection:
    """A table of every sweep point's scalar last-chunk and final metrics (mean ± 95 %
    interval over seeds, a rate's kept in [0, 1]: :func:`seeds_cell`); array-valued metrics
    (e.g. a learned map) stay in ``summary.json`` only."""
    lines = []
    for entry in result.summary.get("points", []):
        label = ", ".join(f"{k}={v}" for k, v in entry["values"].items()) or "default config"
        stats = {**{f"{k} (last chunk)": v for k, v in entry.get("last_chunk", {}).items()},
                 **{f"{k} (final)": v for k, v in entry.get("final", {}).items()}}
        stats = {k: v for k, v in stats.items() if not isinstance(v.get("mean"), list)}
        if not lines:
            lines += ["| point | " + " | ".join(stats) + " |", "|---" * (len(stats) + 1) + "|"]
        lines.append(f"| {label} | " + " | ".join(_cell(k.split(" (")[0], v)
                                                   for k, v in stats.items()) + " |")
    if not lines and "result" in result.summary:
        lines = ["```", str(result.summary["result"]), "```"]
    return ReportSection("\n".join(lines), tuple(result.figures))


def paper_experiments() -> dict[str, Experiment]:
    discover()
    return {n: e for n, e in all_experiments().items() if e.paper_result}


def _url(path: str | Path) -> str:
    """A relative path as a Markdown link target: ``/``-separated and percent-encoded
    (a space, parenthesis or ``#`` in a folder name would end or break the link)."""
    from urllib.parse import quote

    return quote(Path(path).as_posix(), safe="/")


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
        links = [f"![{f.stem}]({_url(os.path.relpath(f, out_dir.absolute()))})" for f in figs]
        path = out_dir / "report.md"
        path.write_text("\n".join([f"# {exp.name}", "", exp.description, "",
                                    section.markdown, "", *(f + "\n" for f in links)]) + "\n")
    finally:
        record_files(out_dir, {p.name for p in out_dir.iterdir()} - before)
    return ReportSection(section.markdown, figs), path


def rerender(folder: str | Path) -> ReportSection:
    """Build a finished run folder's report again (its curves from ``metrics.jsonl``, its
    engine figures as they are) and write its ``report.md``; returns the section."""
    from vbl.engine.plots import plot_names
    from vbl.engine.results import metric_arrays, read_metrics

    exp, res, _ = load_run(folder)
    curves, _ = metric_arrays(read_metrics(Path(folder) / "metrics.jsonl"), len(res.points))
    figures = [p for p in (Path(folder) / n for n in plot_names(curves)) if p.is_file()]
    res = replace(res, curves=curves, figures=figures)
    return run_report(exp, res)[0]


def _rerender_readers(todo: list[Job], exps: dict[str, Experiment], out: Path,
                      done: dict[str, dict[str, Any]]) -> None:
    """The report of each finished run whose experiment reads other runs of this reproduce
    (``Experiment.report_reads``) is built again now that they have all finished (a worker
    builds it when its own run ends, maybe before theirs)."""
    finished = {j.folder for j in todo if done[j.folder]["status"] == "ok"}
    for j in todo:
        reads = set(exps[j.name].report_reads)
        if j.folder not in finished or not reads & finished:
            continue
        try:
            section = rerender(out / j.folder)
        except Exception as e:  # noqa: BLE001 - keep the worker's section, say why
            done[j.folder]["markdown"] += (f"\n\n(built before {sorted(reads & finished)} "
                                           f"finished; building it again failed: {e})")
            continue
        done[j.folder].update(markdown=section.markdown,
                              figures=[str(f) for f in section.figures])


def _cell(name: str, st: dict[str, Any]) -> str:
    """A summary statistic of metric ``name`` as the reports show it: :func:`seeds_cell` of
    its per-seed values (a rate's interval kept in [0, 1]), else mean ± its ``ci95``."""
    m, ci, values = st.get("mean"), st.get("ci95"), st.get("per_seed")
    if not isinstance(m, int | float):
        return str(m)
    if isinstance(values, list) and values and all(isinstance(v, int | float) for v in values):
        return seeds_cell(values, bounds=RATE if is_rate(name) else None)
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
        return _result_line(result.summary.get("result"), width)
    labels = _point_labels(points)
    cols, left = _fit_columns(labels, _headline_names(points[0], exp), points, width)
    seeds = result.summary.get("seeds", result.seeds)
    note = f"mean ± 95% interval over {seeds} seeds"
    if left:
        note += f"; {len(left)} more metric{'s' * (len(left) != 1)} in summary.json"
    return "\n".join(_aligned(cols, len(points)) + [note])


def _result_line(res: Any, width: int) -> str:
    """The headline of a run without sweep points: its result's keys (a dict) or the result
    itself, cut to ``width`` columns; empty without a result."""
    if res is None:
        return ""
    keys = list(res) if isinstance(res, dict) else []
    text = "result keys: " + ", ".join(keys) if keys else "result: " + str(res)
    return text if len(text) <= width else text[:width - 3] + "..."


def _scalar(st: Any) -> bool:
    return isinstance(st, dict) and isinstance(st.get("mean"), int | float)


def _lookup(entry: dict[str, Any], name: str) -> Any:
    """A point's statistic of metric ``name``: the ``final`` one, else the last chunk's."""
    st = entry.get("final", {}).get(name)
    return st if st is not None else entry.get("last_chunk", {}).get(name)


def _headline_names(first: dict[str, Any], exp: Experiment | None) -> list[str]:
    """The metrics a headline table shows, in order: the experiment's
    :attr:`~vbl.engine.Experiment.headline` ones the first point has as scalars, or by
    default the scalar ``final`` metrics then the last chunk's (but ``episodes``)."""
    if exp is not None and exp.headline:
        return [n for n in exp.headline if _scalar(_lookup(first, n))]
    names = [n for n, st in first.get("final", {}).items() if _scalar(st)]
    names += [n for n, st in first.get("last_chunk", {}).items()
              if _scalar(st) and n not in names and n != "episodes"]
    return names


def _point_labels(points: list[dict[str, Any]]) -> list[str]:
    """Each point's swept values (``path=value, ...``), with the last part of each path only
    when a full label would be longer than 40 characters."""
    full = [", ".join(f"{k}={v}" for k, v in e["values"].items()) or "default config"
            for e in points]
    short = [", ".join(f"{k.rsplit('.', 1)[-1]}={v}" for k, v in e["values"].items())
             or "default config" for e in points]
    return full if max(map(len, full)) <= 40 else short


def _fit_columns(labels: list[str], names: list[str], points: list[dict[str, Any]],
                 width: int) -> tuple[list[tuple[str, list[str]]], list[str]]:
    """``([(heading, cells)], metrics left out)``: the point column, then each metric's
    column while the table stays within ``width`` columns (a metric too wide is left out,
    a narrower one after it may still fit)."""
    cols = [("point", labels)]
    used = max(len("point"), *map(len, labels))
    left = []
    for n in names:
        cells = [_cell(n, _lookup(e, n) or {}) for e in points]
        w = max(len(n), *map(len, cells))
        if used + 3 + w > width:
            left.append(n)
            continue
        cols.append((n, cells))
        used += 3 + w
    return cols, left


def _aligned(cols: list[tuple[str, list[str]]], n_rows: int) -> list[str]:
    """The lines of a plain-text table: headings, a rule, ``n_rows`` rows; columns padded to
    their widest cell and joined by `` | ``, trailing spaces cut."""
    widths = [max(len(h), *map(len, c)) for h, c in cols]

    def line(row: list[str]) -> str:
        return " | ".join(x.ljust(w) for x, w in zip(row, widths, strict=True)).rstrip()

    return ([line([h for h, _ in cols]), "-+-".join("-" * w for w in widths)]
            + [line([c[i] for _, c in cols]) for i in range(n_rows)])


REPRODUCE_MANIFEST = "reproduce.json"
"""What ``vbl reproduce`` ran, in order: per run its experiment, preset, folder, status, wall
time and peak memory; the commit, machine and load of the whole run."""

HEARTBEAT_S = 30.0  #: most seconds between two progress lines of ``vbl reproduce``


@dataclass(frozen=True)
class Job:
    """One run of ``vbl reproduce``: an experiment's default config or one of its
    :attr:`~vbl.engine.Experiment.published_presets`, into ``<out>/<folder>``."""

    name: str
    preset: str | None = None

    @property
    def folder(self) -> str:
        return self.name if self.preset is None else f"{self.name}-{self.preset}"


def reproduce_jobs(exps: dict[str, Experiment], quick: bool = False) -> list[Job]:
    """Every published result: each experiment's default, then its published presets;
    ``quick``: the defaults only (a preset is a variant of a paper result, published from
    the full run; the quick run is the paper's experiments once, in minutes)."""
    return [Job(n, p) for n, e in exps.items()
            for p in (None, *(() if quick else e.published_presets))]


def default_jobs(n_runs: int) -> int:
    """Worker processes for ``vbl reproduce``: one per CPU core, at most one per run.

    A quick run is dominated by XLA compilation, which uses one core per program, so
    runs in separate processes use every core while they compile.
    """
    return max(1, min(os.cpu_count() or 1, n_runs))


def _peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MiB (Linux reports KiB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _run_one(job: Job, out: Path, quick: bool, quiet: bool | None, resume: bool,
             overwrite: bool, exp: Experiment | None = None) -> dict[str, Any]:
    """Run one job and build its report section; never raises.

    In a worker process ``exp`` is None and the experiment is looked up in the registry
    (the worker imports the experiment scripts itself). Returns a picklable dict.
    """
    from vbl.engine.runner import run_experiment

    t0 = time.perf_counter()
    result = None
    folder = out / job.folder
    try:
        if exp is None:
            exp = paper_experiments()[job.name]
        result = run_experiment(exp, out=folder, quick=quick, quiet=quiet, preset=job.preset,
                                resume=resume and folder.exists(), overwrite=overwrite)
        section, _ = run_report(exp, result)
        status = "ok"
    except Exception as e:  # noqa: BLE001 - report and continue with the others
        status = f"failed: {type(e).__name__}: {e}"
        section = ReportSection("**failed**\n\n```\n" + "".join(
            traceback.format_exception(type(e), e, e.__traceback__))[-3000:] + "```")
    figs = [str(_figure_path(f, result.out_dir if result is not None else Path.cwd()))
            for f in section.figures]
    return dict(status=status, markdown=section.markdown, figures=figs,
                seconds=time.perf_counter() - t0, peak_rss_mb=_peak_rss_mb())


def _run_chain(jobs: list[Job], out: Path, quick: bool, resume: bool, overwrite: bool
               ) -> dict[str, dict]:
    """Worker task: run jobs one after the other (one :attr:`Experiment.group`)."""
    from vbl.engine.errors import quiet_xla_log
    from vbl.engine.jax_setup import use_compilation_cache

    quiet_xla_log()
    use_compilation_cache()
    try:
        return {j.folder: _run_one(j, out, quick, True, resume, overwrite) for j in jobs}
    except KeyboardInterrupt:  # SIGTERM from the parent, the run unwound: end this worker
        os._exit(143)  # at once (the parent's pool then starts no other)


def _worker_init(out: Path) -> None:
    """A reproduce worker: the parent stops it (SIGINT ignored, SIGTERM unwinds the run),
    and it may write the runs of the reproduce folder ``out``, which the parent holds
    locked."""
    from vbl.engine.errors import debug_requested, quiet_library_noise, worker_stop_handlers
    from vbl.engine.runfolder import allow_runs_under

    worker_stop_handlers()
    if not debug_requested():
        quiet_library_noise()
    allow_runs_under(out)


WORKER_STOP_S = 1.5
"""Seconds a worker has to end after SIGTERM when ``vbl reproduce`` stops, before it is
killed (its run folder stays consistent either way: rows are appended whole, checkpoints
are written then renamed)."""


def _workers(pool) -> dict:
    """The pool's ``{pid: process}``, the live dict its manager thread updates (the pool
    drops its own reference at shutdown)."""
    procs = getattr(pool, "_processes", None)
    return procs if procs is not None else {}


def _stop_workers(pool, workers: dict, futures) -> None:
    """Cancel the queued ``futures`` of ``pool``, SIGTERM every worker process
    (``workers``, from :func:`_workers`; a stopped worker exits at once, which breaks the
    pool, so it starts no other), SIGKILL those still running after
    :data:`WORKER_STOP_S`, then shut the pool down."""
    for f in futures:
        f.cancel()
    deadline = time.monotonic() + WORKER_STOP_S
    signalled: set[int] = set()
    while True:  # the pool may have started a worker meanwhile: look again until none runs
        procs = [p for p in list(workers.values()) if p.is_alive()]
        if not procs:
            break
        for p in procs:
            with contextlib.suppress(Exception):
                if p.pid not in signalled:
                    p.terminate()
                    signalled.add(p.pid)
                elif time.monotonic() >= deadline:
                    p.kill()
        time.sleep(0.05)
    manager = getattr(pool, "_executor_manager_thread", None)
    if manager is not None:
        manager.join(2.0)  # it ends once it has seen the pool broken
    with contextlib.suppress(Exception):
        pool.shutdown(wait=False, cancel_futures=True)


def _kill_workers(workers: dict) -> None:
    for p in list(workers.values()):
        with contextlib.suppress(Exception):
            p.kill()


COMMITTED_RUNS = Path(__file__).resolve().parents[2] / "docs" / "results"
"""A source checkout's committed ``vbl reproduce`` runs (``reproduce`` and
``reproduce-quick``): their manifests' per-run seconds order the next run's jobs."""


def committed_seconds(quick: bool, root: Path = COMMITTED_RUNS) -> dict[str, float]:
    """``{run folder: seconds}`` of the committed ``vbl reproduce`` run at this scale
    (``root/reproduce-quick`` or ``root/reproduce``), ``{}`` without one (an installed
    package)."""
    path = root / ("reproduce-quick" if quick else "reproduce") / REPRODUCE_MANIFEST
    try:
        runs = json.loads(path.read_text())["runs"]
        return {r["folder"]: float(r["seconds"]) for r in runs if "seconds" in r}
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def _chains(jobs: list[Job], exps: dict[str, Experiment], seconds: dict[str, float]
            ) -> list[list[Job]]:
    """Jobs grouped by :attr:`Experiment.group` (registry order inside a group), longest
    chain first by ``seconds`` (per run folder, :func:`committed_seconds`; a run without
    a time counts the mean of the others, so a new result neither starts first nor last)."""
    default = sum(seconds.values()) / len(seconds) if seconds else 1.0
    chains: dict[str, list[Job]] = {}
    for j in jobs:
        e = exps[j.name]
        chains.setdefault(e.group if e.group is not None else f"\0{j.folder}", []).append(j)
    return sorted(chains.values(), key=lambda c: -sum(seconds.get(j.folder, default)
                                                      for j in c))


def _progress_line(out: Path, running: list[Job], n_done: int, n_all: int, t0: float) -> str:
    """One line: runs done, and per running run its phase and chunks (from the status file
    its runner writes, :data:`vbl.engine.progress.STATUS_FILE`)."""
    from vbl.engine.progress import read_status

    parts = []
    for j in running:  # a queued job counts as running before its worker takes it
        st = read_status(out / j.folder)
        if st or (out / j.folder).exists():
            parts.append(f"{j.folder} {st or 'running'}")
    elapsed = round(time.perf_counter() - t0)  # whole seconds: never "29 min 60 s"
    return (f"vbl reproduce [{n_done}/{n_all} done, {elapsed // 60} min "
            f"{elapsed % 60:02d} s] " + ("; ".join(parts) if parts else "finishing"))


def _run_parallel(jobs: list[Job], exps: dict[str, Experiment], workers: int, out: Path,
                  quick: bool, resume: bool, overwrite: bool, quiet: bool | None
                  ) -> dict[str, dict]:
    """Run jobs in ``workers`` spawned processes (a fresh one per chain, so each run's peak
    memory is its own), costliest chain first, with a progress line at least every
    :data:`HEARTBEAT_S` seconds."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    from vbl.engine.errors import on_forced_exit

    done: dict[str, dict] = {}
    started = time.time()
    ctx = multiprocessing.get_context("spawn")  # jax is not fork-safe
    t0 = last = time.perf_counter()
    chains = _chains(jobs, exps, committed_seconds(quick))
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, max_tasks_per_child=1,
                               initializer=_worker_init, initargs=(out,))
    procs = _workers(pool)
    forget = on_forced_exit(lambda: _kill_workers(procs))
    try:
        futures = {pool.submit(_run_chain, c, out, quick, resume, overwrite): c
                   for c in chains}
        pending = set(futures)
        while pending:
            finished, pending = wait(pending, timeout=5.0, return_when=FIRST_COMPLETED)
            for fut in finished:
                try:
                    results = fut.result()
                except Exception as e:  # noqa: BLE001 - a worker died (killed, out of memory)
                    results = {j.folder: _after_dead_worker(j, e, exps, out, quick, started)
                               for j in futures[fut]}
                for name, r in results.items():
                    done[name] = r
                    if not quiet:
                        print(f"[{len(done)}/{len(jobs)}] {name}: "
                              f"{r['status'].splitlines()[0]} ({r['seconds']:.0f} s)", flush=True)
            now = time.perf_counter()
            if not quiet and pending and now - last >= HEARTBEAT_S - 2.5:
                running = [j for f in pending if f.running() for j in futures[f]
                           if j.folder not in done]
                print(_progress_line(out, running, len(done), len(jobs), t0), flush=True)
                last = now
    except BaseException as e:  # SIGINT / SIGTERM (or a failure here): stop every worker
        _stop_workers(pool, procs, futures if "futures" in locals() else ())
        if isinstance(e, KeyboardInterrupt):
            raise type(e)(_stopped(e, out, len(done), len(jobs))) from None
        raise
    else:
        pool.shutdown(wait=True)
    finally:
        forget()
    return done


def _after_dead_worker(job: Job, e: BaseException, exps: dict[str, Experiment], out: Path,
                       quick: bool, started: float) -> dict[str, Any]:
    """A job whose worker died: a run that finished before (its ``summary.json`` written
    since ``started``) is complete, so its report is rebuilt here (``--resume`` of a
    finished run runs nothing); any other is failed."""
    summary = out / job.folder / "summary.json"
    try:
        finished = summary.stat().st_mtime >= started - 1.0
    except OSError:
        finished = False
    if finished:
        r = _run_one(job, out, quick, True, True, False, exp=exps[job.name])
        if r["status"] == "ok":
            return r
    return dict(status=f"failed: worker process died: {e!r}",
                markdown="**failed** (worker process died)", figures=[],
                seconds=float("nan"), peak_rss_mb=float("nan"))


def _stopped(e: BaseException, out: Path, n_done: int, n_all: int) -> str:
    from vbl.engine.errors import stop_message

    return (f"{stop_message(e)}; {n_done} of {n_all} runs finished and are kept in {out}; "
            f"continue with vbl reproduce --resume --out {out}")


def _load() -> float | None:
    """The load average for the manifest, to 2 decimals (None where there is none)."""
    load = load_average()
    return None if load is None else round(load, 2)


def reproduce(out: Path, *, quick: bool, quiet: bool | None, resume: bool = False,
              overwrite: bool = False, names: list[str] | None = None,
              jobs: int | None = 1) -> tuple[Path, bool]:
    """Run every published result (:func:`reproduce_jobs`) into ``out/<folder>/`` and write
    ``out/report.md`` and ``out/reproduce.json``.

    ``jobs``: worker processes (None: :func:`default_jobs`; 1: in this process, in
    registry order). With ``jobs > 1`` every run goes quietly in a spawned process that
    imports the experiment scripts itself, so only discoverable experiments (scripts in the
    experiments folders) can run there. Results do not depend on ``jobs``.
    Returns ``(report path, all succeeded)``. A failing run is reported and the others
    still run.
    """
    from vbl.engine.runfolder import check_new_folder, lock_reproduce_folder
    from vbl.params import ParamError

    exps = paper_experiments()
    if names:
        bad = [n for n in names if n not in exps]
        if bad:  # bad input: exit 2
            raise ParamError(f"unknown paper experiment(s) {bad}; valid: {sorted(exps)}")
        exps = {n: exps[n] for n in names}
    out = Path(out)
    if not (resume or overwrite):
        check_new_folder(out, resume=False, overwrite=False)  # raises clearly
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise EngineError(f"cannot write to output folder {out}: {e.strerror or e}") from e
    try:
        lock = lock_reproduce_folder(out)  # for the reproduce's whole life
    except BaseException:
        if created:  # an empty folder it made (the lock file stays: never delete one)
            with contextlib.suppress(OSError):
                out.rmdir()
        raise
    try:
        return _reproduce(exps, out, quick, quiet, resume, overwrite, jobs)
    finally:
        lock.release()


def _reproduce(exps: dict[str, Experiment], out: Path, quick: bool, quiet: bool | None,
               resume: bool, overwrite: bool, jobs: int | None) -> tuple[Path, bool]:
    from vbl.engine.results import write_json

    todo = reproduce_jobs(exps, quick)
    workers = default_jobs(len(todo)) if jobs is None else max(1, min(int(jobs), len(todo)))
    load_start, t_start = _load(), time.perf_counter()
    if quiet is not True:
        print(f"vbl reproduce{' --quick' if quick else ''}: {len(todo)} runs in {workers} "
              f"worker process{'es' * (workers > 1)} -> {out}", flush=True)
    if workers > 1:
        done = _run_parallel(todo, exps, workers, out, quick, resume, overwrite, quiet)
    else:
        done = {}
        try:
            for j in todo:
                done[j.folder] = _run_one(j, out, quick, quiet, resume, overwrite,
                                          exp=exps[j.name])
        except KeyboardInterrupt as e:  # SIGINT / SIGTERM: the finished runs are kept
            raise type(e)(_stopped(e, out, len(done), len(todo))) from None
    _rerender_readers(todo, exps, out, done)
    wall = time.perf_counter() - t_start
    manifest = {"quick": quick, "commit": git_commit(), "machine": machine_description(),
                "workers": workers, "wall_s": round(wall, 1),
                "load_average": [load_start, _load()],
                "runs": [{"experiment": j.name, "preset": j.preset, "folder": j.folder,
                          "status": done[j.folder]["status"].splitlines()[0],
                          "seconds": round(done[j.folder]["seconds"], 1),
                          "peak_rss_mb": round(done[j.folder]["peak_rss_mb"])}
                         for j in todo]}
    write_json(out / REPRODUCE_MANIFEST, manifest)
    parts = [f"# vbl reproduction report{' (--quick)' if quick else ''}", "",
             f"{wall:.0f} s wall in {workers} worker process{'es' * (workers > 1)} on "
             f"{manifest['machine']}, load average {load_start} at the start; code "
             f"{manifest['commit']}. Each section puts vbl's numbers beside the paper's.", ""]
    ok = True
    rows, sections = [], []
    for j in todo:
        r, exp = done[j.folder], exps[j.name]
        ok &= r["status"] == "ok"
        what = exp.description + (f" (preset `{j.preset}`)" if j.preset else "")
        rows.append(f"| {j.folder} | {what} | {r['status'].splitlines()[0]} | "
                    f"{r['seconds']:.0f} |")
        figs = [f"![{Path(f).stem}]({_url(os.path.relpath(f, out.absolute()))})"
                for f in r["figures"]]
        sections += [f"## {j.folder}", "", what, "", r["markdown"], "",
                     *(f + "\n" for f in figs), ""]
    for path, err in import_errors().items():
        rows.append(f"| {Path(path).stem} | (script failed to import) | failed: {err} | |")
        ok = False
    parts += ["| run | what | status | time (s) |", "|---|---|---|---|", *rows, "",
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


RATE = (0.0, 1.0)  #: range of a success rate (``bounds`` of :func:`seeds_cell`)


def seeds_cell(values: Any, scale: float = 1.0, fmt: str = ".3g",
               bounds: tuple[float, float] | None = None) -> str:
    """``"mean ± half-width"`` of per-seed values (95 % Student t interval of the mean),
    scaled by ``scale``. With ``bounds``, the range of the metric before scaling (e.g.
    :data:`RATE`), the interval stays in it: ``"mean [lower, upper]"`` where the t
    interval crosses the range, and ``"mean (n seeds: too few for an interval)"`` where it
    does so with fewer than :data:`vbl.stats.MIN_SEEDS_BOUNDED` seeds."""
    import numpy as np

    from vbl.stats import bounded_ci95

    x = np.asarray(values, np.float64).ravel()
    m, half = mean_ci95(x)
    f = lambda v: format(v * scale, fmt)  # noqa: E731
    if half != half:
        return f(m)
    if bounds is None or bounds[0] <= m - half and m + half <= bounds[1]:
        return f"{f(m)} ± {format(half * scale, fmt)}"
    b = bounded_ci95(x, *bounds)
    if b is None:
        return f"{f(m)} ({x.size} seeds: too few for an interval)"
    return f"{f(m)} [{f(b[1])}, {f(b[2])}]"


def rate_cell(values: Any, scale: float = 1.0, fmt: str = ".3f") -> str:
    """:func:`seeds_cell` of a success rate in [0, 1] (shown times ``scale``)."""
    return seeds_cell(values, scale, fmt, RATE)


def claim(a: Any, b: Any, paired: bool = False, fmt: str = ".3g") -> str:
    """Verdict on "mean(a) > mean(b)" over seeds: "yes" when the 95 % interval of the
    difference (Welch's; with ``paired``, Student's on the per-seed differences) lies above
    0, "**no**" when it lies below, else "not resolved" with the number of seeds that would
    resolve a difference of this size. A verdict never rests on two means alone."""
    import numpy as np

    from vbl.stats import seeds_to_resolve, welch_ci95

    a, b = np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()
    d, h = mean_ci95(a - b) if paired else welch_ci95(a, b)
    n = min(a.size, b.size)
    diff = f"{format(d, '+' + fmt)} ± {format(h, fmt)}" if h == h else format(d, "+" + fmt)
    if h != h:
        return f"not resolved ({n} seed{'s' * (n != 1)}: no interval; {diff})"
    if d - h > 0:
        return f"yes ({diff})"
    if d + h < 0:
        return f"**no** ({diff})"
    need = seeds_to_resolve(d, h, n)
    more = (f"; about {need} seeds would resolve a difference this size" if need else "")
    return f"not resolved at {n} seeds ({diff}{more})"


def load_run(folder: str | Path, shard_ok: bool = False
             ) -> tuple[Experiment, RunResult, dict[str, Any]]:
    """``(experiment, RunResult, config.json)`` of a finished run folder. The result is
    rebuilt from ``config.json`` and ``summary.json``: ``final`` holds the per-seed values
    (``[points, seeds]``), ``curves`` is empty, ``config`` is the experiment's default
    config with the folder's recorded values. A folder of another run-folder format, or
    one that records parameters the experiment does not have, is an EngineError, and so is
    one shard of a run (``vbl run --shard``) unless ``shard_ok`` (``vbl merge`` reads them)."""
    from vbl.engine.registry import get
    from vbl.engine.results import read_json
    from vbl.engine.runfolder import check_fingerprint, check_format

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
    from vbl.engine.runner import defaults_spec

    out = defaults_spec(spec)
    if isinstance(summary, dict):
        got = {k: summary[k] for k in ("seeds", "sweep") if k in summary}
        if got:
            out.append({**{k: v for k, v in spec.items() if k != "fingerprint"}, **got})
    return out


def _recorded_config(exp: Experiment, spec: dict[str, Any], folder: Path) -> Any:
    from vbl.engine.config import apply_overrides
    from vbl.params import ParamError

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
    ``--sweep`` per swept path whose values differ from the default sweep's, a ``--set`` per
    default-swept path the run did not sweep, and per other value that differs from what
    ``--quick`` and the preset give."""
    from vbl.engine.runner import resolve

    default_sweep = {k: config_to_dict_values({"v": list(v)})["v"] for k, v in exp.sweep.items()}
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
    from vbl.engine.config import parse_assignment, parse_sweep
    from vbl.engine.runner import resolve

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
    from vbl.engine.results import read_json

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
        rel = _url(os.path.relpath(Path(folder).absolute(), base))
        name = Path(folder).name.replace("[", "\\[").replace("]", "\\]")
        link = (f"[{name}]({rel}/report.md)" if (Path(folder) / "report.md")
                .is_file() else f"[{name}]({rel}/)")
        for i, r in enumerate(rows):
            first = i == 0
            lines.append(f"| {r.result} | {r.paper} | {r.ours} | {result.seeds if first else ''}"
                         f" | {link if first else ''} | {f'`{command}`' if first else ''} |")
    return "\n".join(lines) + "\n"
