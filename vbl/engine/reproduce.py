"""``vbl reproduce``: run every published result (paper experiments and their published
presets) in worker processes, longest first, and write one ``report.md`` and the
manifest ``reproduce.json`` for all of them."""

from __future__ import annotations

import contextlib
import json
import math
import multiprocessing
import os
import resource
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vbl.engine.errors import (
    EngineError,
    debug_requested,
    on_forced_exit,
    quiet_library_noise,
    quiet_xla_log,
    stop_hint,
    stop_message,
    worker_stop_handlers,
)
from vbl.engine.experiment import Experiment, ReportSection
from vbl.engine.jax_setup import EXECUTION_LOCK_ENV, use_compilation_cache
from vbl.engine.machine import git_commit, load_average, machine_description
from vbl.engine.progress import read_status
from vbl.engine.rebuild import REPRODUCE_MANIFEST, rerender
from vbl.engine.registry import all_experiments, discover, import_errors
from vbl.engine.report import figure_path, run_report, url_path
from vbl.engine.results import write_json
from vbl.engine.runfolder import allow_runs_under, check_new_folder, lock_reproduce_folder
from vbl.engine.runner import run_experiment
from vbl.engine.trace_cache import use_trace_cache
from vbl.params import ParamError

__all__ = ["reproduce", "reproduce_jobs", "Job", "default_jobs", "paper_experiments",
           "committed_seconds", "COMMITTED_RUNS", "HEARTBEAT_S", "RUN_COSTS"]


def paper_experiments() -> dict[str, Experiment]:
    discover()
    return {n: e for n, e in all_experiments().items() if e.paper_result}


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


RUN_COSTS = ("seconds", "cpu_s", "peak_rss_mb")
"""What the manifest records of each run: wall seconds from its start in its worker, CPU
seconds of the worker process in that time (all threads: XLA compiles and runs on several),
peak resident memory of the worker (MiB)."""

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
    ``quick``: the defaults of the experiments ``in_quick_reproduce`` only (a preset is a
    variant of a paper result, published from the full run; the quick run is the paper's
    experiments once, in minutes)."""
    return [Job(n, p) for n, e in exps.items() if e.in_quick_reproduce or not quick
            for p in (None, *(() if quick else e.published_presets))]


def default_jobs(n_runs: int) -> int:
    """Worker processes for ``vbl reproduce``: one per CPU core, at most one per run.

    A quick run is dominated by tracing and XLA compilation, about one core per program,
    so runs in separate processes use every core while they compile; their compiled
    programs, which use every core each, take turns (:func:`_execution_lock_for_workers`).
    A full-scale run's programs run side by side: they leave gaps in each other's use of
    the cores, which turns would leave idle.
    """
    return max(1, min(os.cpu_count() or 1, n_runs))


def _peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _run_one(job: Job, out: Path, quick: bool, quiet: bool | None, resume: bool,
             overwrite: bool, exp: Experiment | None = None) -> dict[str, Any]:
    """Run one job and build its report section; never raises.

    In a worker process ``exp`` is None and the experiment is looked up in the registry
    (the worker imports the experiment scripts itself). Returns a picklable dict.
    """
    t0, cpu0 = time.perf_counter(), time.process_time()
    result = None
    folder = out / job.folder
    try:
        if exp is None:
            exp = paper_experiments()[job.name]
        result = run_experiment(exp, out=folder, quick=quick, quiet=quiet, preset=job.preset,
                                resume=resume and folder.exists(), overwrite=overwrite,
                                report=False)  # its section, built here, goes in both
        section, _ = run_report(exp, result)
        status = "ok"
    except Exception as e:  # noqa: BLE001 - report and continue with the others
        status = f"failed: {type(e).__name__}: {e}"
        section = ReportSection("**failed**\n\n```\n" + "".join(
            traceback.format_exception(type(e), e, e.__traceback__))[-3000:] + "```")
    figs = [str(figure_path(f, result.out_dir if result is not None else Path.cwd()))
            for f in section.figures]
    return dict(status=status, markdown=section.markdown, figures=figs,
                seconds=time.perf_counter() - t0, cpu_s=time.process_time() - cpu0,
                peak_rss_mb=_peak_rss_mb())


def _run_chain(jobs: list[Job], out: Path, quick: bool, resume: bool, overwrite: bool
               ) -> dict[str, dict]:
    """Worker task: run jobs one after the other (one :attr:`Experiment.group`)."""
    quiet_xla_log()
    use_compilation_cache()
    use_trace_cache()
    try:
        return {j.folder: _run_one(j, out, quick, True, resume, overwrite) for j in jobs}
    except KeyboardInterrupt:  # SIGTERM from the parent, the run unwound: end this worker
        os._exit(143)  # at once (the parent's pool then starts no other)


def _worker_init(out: Path) -> None:
    """A reproduce worker: the parent stops it (SIGINT ignored, SIGTERM unwinds the run),
    and it may write the runs of the reproduce folder ``out``, which the parent holds
    locked."""
    worker_stop_handlers()
    if not debug_requested():
        quiet_library_noise()
    allow_runs_under(out)


WORKER_STOP_S = 1.5
"""Seconds a worker has to end after SIGTERM when ``vbl reproduce`` stops, before it is
killed (its run folder stays consistent either way: rows are appended whole, checkpoints
are written then renamed)."""


def _execution_lock_for_workers() -> Callable[[], None]:
    """Point ``VBL_EXECUTION_LOCK`` at a fresh lock file, which the workers spawned from now
    on inherit, so that they take turns at running programs
    (:func:`vbl.engine.jax_setup.execution_turn`; a variable already set is kept). Returns
    the function that removes the variable and the file."""
    if os.environ.get(EXECUTION_LOCK_ENV, "").strip():
        return lambda: None
    fd, path = tempfile.mkstemp(prefix="vbl-execution-", suffix=".lock")
    os.close(fd)
    os.environ[EXECUTION_LOCK_ENV] = path

    def forget() -> None:
        os.environ.pop(EXECUTION_LOCK_ENV, None)
        with contextlib.suppress(OSError):
            os.unlink(path)
    return forget


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
        return {r["folder"]: float(r["seconds"]) for r in runs
                if r.get("seconds") is not None}
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
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait


    done: dict[str, dict] = {}
    started = time.time()
    ctx = multiprocessing.get_context("spawn")  # jax is not fork-safe
    t0 = last = time.perf_counter()
    chains = _chains(jobs, exps, committed_seconds(quick))
    # before the pool spawns its workers; turns only at quick scale (default_jobs)
    forget_lock = _execution_lock_for_workers() if quick else (lambda: None)
    try:
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, max_tasks_per_child=1,
                                   initializer=_worker_init, initargs=(out,))
    except BaseException:
        forget_lock()
        raise
    procs = _workers(pool)
    forget = on_forced_exit(lambda: _kill_workers(procs))
    forget_hint = stop_hint(lambda: _resume_tail(out, len(done), len(jobs)))
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
                              f"{r['status'].splitlines()[0]} ({_seconds(r)})", flush=True)
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
        forget_hint()
        forget_lock()
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
                seconds=float("nan"), cpu_s=float("nan"), peak_rss_mb=float("nan"))


def _stopped(e: BaseException, out: Path, n_done: int, n_all: int) -> str:
    return f"{stop_message(e)}; {_resume_tail(out, n_done, n_all)}"


def _resume_tail(out: Path, n_done: int, n_all: int) -> str:
    """What a stopped reproduce's line says after the stop: what is kept, how to go on."""
    return (f"{n_done} of {n_all} runs finished and are kept in {out}; "
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
    exps = paper_experiments()
    if names:
        bad = [n for n in names if n not in exps]
        if bad:  # bad input: exit 2
            raise ParamError(f"unknown paper experiment(s) {bad}; valid: {sorted(exps)}")
        full_only = [n for n in names if quick and not exps[n].in_quick_reproduce]
        if full_only:
            raise ParamError(f"{full_only[0]} runs in the full reproduce only (its quick "
                             f"scale trains too little to show its result): drop --quick, "
                             f"or run `vbl run {full_only[0]} --quick`")
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


def _number(value: Any) -> float:
    """A cost read from a manifest: NaN for one it lacks (absent, or null)."""
    return math.nan if value is None else float(value)


def _seconds(r: dict[str, Any]) -> str:
    """A run's wall time for a progress line or the report: ``"12 s"``, or ``"-"`` when
    it was not measured."""
    return f"{r['seconds']:.0f} s" if math.isfinite(r["seconds"]) else "-"


def _costs(r: dict[str, Any]) -> dict[str, float | int | None]:
    """A run's :data:`RUN_COSTS` for the manifest: seconds and CPU seconds to 0.1 s, peak
    memory in whole MB, None (JSON null) for one that was not measured (a run whose worker
    died)."""
    def rounded(x: float, digits: int | None) -> float | int | None:
        return round(x, digits) if math.isfinite(x) else None
    return {"seconds": rounded(r["seconds"], 1), "cpu_s": rounded(r["cpu_s"], 1),
            "peak_rss_mb": rounded(r["peak_rss_mb"], None)}


def _finished_times(out: Path, todo: list[Job]) -> dict[str, dict[str, float]]:
    """``{folder: {seconds, cpu_s, peak_rss_mb}}`` from ``out``'s manifest for the runs
    that had finished before a ``--resume`` (their ``summary.json`` is there): the resume
    runs nothing for them, and the manifest keeps what they took (NaN, written as null, for
    a cost the manifest lacks: one written before it recorded CPU time)."""
    try:
        runs = json.loads((out / REPRODUCE_MANIFEST).read_text())["runs"]
        before = {r["folder"]: r for r in runs if r.get("status") == "ok"}
    except (OSError, ValueError, KeyError, TypeError):
        return {}
    return {j.folder: {k: _number(before[j.folder].get(k)) for k in RUN_COSTS}
            for j in todo if j.folder in before and (out / j.folder / "summary.json").is_file()}


def _reproduce(exps: dict[str, Experiment], out: Path, quick: bool, quiet: bool | None,
               resume: bool, overwrite: bool, jobs: int | None) -> tuple[Path, bool]:
    todo = reproduce_jobs(exps, quick)
    kept = _finished_times(out, todo) if resume else {}
    workers = default_jobs(len(todo)) if jobs is None else max(1, min(int(jobs), len(todo)))
    load_start, t_start = _load(), time.perf_counter()
    if quiet is not True:
        print(f"vbl reproduce{' --quick' if quick else ''}: {len(todo)} runs in {workers} "
              f"worker process{'es' * (workers > 1)} -> {out}", flush=True)
    if workers > 1:
        done = _run_parallel(todo, exps, workers, out, quick, resume, overwrite, quiet)
    else:
        done = {}
        forget_hint = stop_hint(lambda: _resume_tail(out, len(done), len(todo)))
        try:
            for j in todo:
                done[j.folder] = _run_one(j, out, quick, quiet, resume, overwrite,
                                          exp=exps[j.name])
        except KeyboardInterrupt as e:  # SIGINT / SIGTERM: the finished runs are kept
            raise type(e)(_stopped(e, out, len(done), len(todo))) from None
        finally:
            forget_hint()
    _rerender_readers(todo, exps, out, done)
    for folder, times in kept.items():  # a resume ran nothing for them: their own times
        if done[folder]["status"] == "ok":
            done[folder].update(times)
    wall = time.perf_counter() - t_start
    manifest = {"quick": quick, "commit": git_commit(), "machine": machine_description(),
                "workers": workers, "wall_s": round(wall, 1),
                "load_average": [load_start, _load()],
                "runs": [{"experiment": j.name, "preset": j.preset, "folder": j.folder,
                          "status": done[j.folder]["status"].splitlines()[0],
                          **_costs(done[j.folder])}
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
                    f"{_seconds(r).removesuffix(' s')} |")
        figs = [f"![{Path(f).stem}]({url_path(os.path.relpath(f, out.absolute()))})"
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
