"""The ``vbl`` command: list, run, merge, reproduce, report, export, plot, tune, bench,
params (see docs/engine.md), render (docs/render.md)."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
import warnings
from pathlib import Path

from vbl.engine.process import (
    end_process,
    quiet_process,
    quiet_xla,
    rerun_with_quiet_xla,
    use_all_cores,
)

__all__ = ["main", "main_for", "build_parser"]


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line ``vbl: error: ...`` for bad command lines (exit 2)."""

    def error(self, message: str):
        self.exit(2, f"vbl: error: {message} (see {self.prog} --help)\n")


def _add_debug(p: argparse.ArgumentParser, default=False) -> None:
    p.add_argument("--debug", action="store_true", default=default,
                   help="show the traceback of an error (or set VBL_DEBUG=1)")


def _add_run_options(p: argparse.ArgumentParser) -> None:
    from vbl.engine.runfolder import DEFAULT_CHECKPOINT_EVERY, DEFAULT_LEARNER_BATCH

    p.add_argument("--set", dest="sets", action="append", default=[], metavar="PATH=VALUE",
                   help="override a parameter, e.g. --set agent.learning_rate=0.1 (a path "
                        "of the experiment's default sweep is then fixed)")
    p.add_argument("--preset", default=None, metavar="NAME",
                   help="a named variant of the experiment (its values; --set and --sweep "
                        "still override them); `vbl params EXPERIMENT` lists the presets")
    p.add_argument("--sweep", action="append", default=[], metavar="PATH=V1,V2,...",
                   help="sweep a parameter over values (repeat for a grid; the experiment's "
                        "default sweep stays for the paths not named; the run prints its "
                        "points first)")
    p.add_argument("--seeds", type=int, default=None, help="seeds per sweep point")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--out", default=None, help="run folder (default runs/<name>-<time>)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true", help="continue from the last checkpoint")
    g.add_argument("--overwrite", action="store_true", help="replace an existing run folder")
    p.add_argument("--quick", action="store_true", help="small, fast version")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--checkpoint-every", type=int, default=DEFAULT_CHECKPOINT_EVERY,
                   metavar="K", help=f"chunks between checkpoints "
                                     f"(default {DEFAULT_CHECKPOINT_EVERY})")
    p.add_argument("--learner-batch", type=int, default=DEFAULT_LEARNER_BATCH, metavar="B",
                   help=f"most learners per compiled call (default {DEFAULT_LEARNER_BATCH})")
    p.add_argument("--shard", default=None, metavar="I/N",
                   help="run only part I of N of the learners (seeds x sweep points, the "
                        "keys of the whole run) into this run folder; `vbl merge` joins the "
                        "N folders")
    p.add_argument("--coordinator", default=None, metavar="HOST:PORT|auto",
                   help="multi-process coordinator (or VBL_COORDINATOR); auto: JAX detects "
                        "it and the process count and id (SLURM, Open MPI, Kubernetes, "
                        "Cloud TPU)")
    p.add_argument("--num-processes", type=int, default=None,
                   help="number of processes (or VBL_NUM_PROCESSES)")
    p.add_argument("--process-id", type=int, default=None,
                   help="this process's id (or VBL_PROCESS_ID)")
    p.add_argument("--no-memory-check", action="store_true",
                   help="run even when the memory estimate exceeds the memory available")
    p.add_argument("--tensorboard", default=None, metavar="DIR",
                   help="also write each sweep point's mean curve and 95%% band per chunk as "
                        "TensorBoard event files to DIR (tensorboard --logdir DIR; needs "
                        "tensorboardX)")
    _add_debug(p, argparse.SUPPRESS)


def _add_render(sub) -> None:
    """The ``vbl render`` subcommand (docs/render.md, "Videos")."""
    p = sub.add_parser("render", help="a video (GIF or MP4) of a run folder's policy: camera "
                       "view, top view, the learner's state and action (docs/render.md)")
    p.add_argument("folder", metavar="RUN_FOLDER", help="a finished run folder (vbl run --out)")
    p.add_argument("--episodes", type=int, default=2, metavar="N",
                   help="episodes, one after the other (default 2)")
    p.add_argument("--out", required=True, metavar="FILE", help="FILE.gif or FILE.mp4")
    p.add_argument("--policy", default="learned", metavar="learned|random",
                   help="the run's final Q table (needs its checkpoints/) or the uniformly "
                        "random policy (default learned)")
    p.add_argument("--point", type=int, default=0,
                   help="sweep point of the run (index, default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the run (index, default 0)")
    p.add_argument("--key", type=int, default=0, help="PRNG seed of the episodes' starts")
    p.add_argument("--height", type=int, default=None, metavar="PX",
                   help="frame height (default 128)")
    p.add_argument("--max-steps", type=int, default=None, metavar="T",
                   help="most primitives (frames) per episode (default 200)")
    _add_debug(p, argparse.SUPPRESS)


def _add_data_commands(sub) -> None:
    """``vbl export`` and ``vbl plot``: a run folder's results as data (docs/engine.md)."""
    p = sub.add_parser("export", help="a run folder (finished, running or merged) as one "
                       "table: a row per sweep point, seed, chunk and metric (needs pandas)")
    p.add_argument("folder", metavar="RUN_DIR", help="a run folder (vbl run --out)")
    p.add_argument("--format", default=None, choices=("csv", "parquet"),
                   help="file format (default: --out's extension, else csv)")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="the table's file (default RUN_DIR's name and the format's extension, "
                        "in the current folder)")
    p.add_argument("--final", action="store_true",
                   help="the final metrics per sweep point instead: mean, std and 95%% "
                        "interval over seeds")
    _add_debug(p, argparse.SUPPRESS)
    p = sub.add_parser("plot", help="a final metric of a run folder against a swept "
                       "parameter: mean and 95%% interval, a line per other swept value")
    p.add_argument("folder", metavar="RUN_DIR", help="a run folder (vbl run --out)")
    p.add_argument("--x", required=True, metavar="PARAM",
                   help="the swept parameter (its path, or the path's last part)")
    p.add_argument("--y", required=True, metavar="METRIC",
                   help="the metric (Program.final's, else the last chunk's)")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="FILE.png or FILE.svg (default METRIC_vs_PARAM.png)")
    _add_debug(p, argparse.SUPPRESS)


def _add_tune(sub) -> None:
    """The ``vbl tune`` subcommand (docs/engine.md, "Hyperparameter search")."""
    p = sub.add_parser("tune", help="a hyperparameter search (Optuna): batches of trials x "
                       "seeds run as one sweep each, optional successive halving, the best "
                       "trial confirmed on fresh seeds (needs optuna: pip install 'vbl[tune]')")
    p.add_argument("experiment", help="experiment name, or path/to/script.py")
    p.add_argument("--space", action="append", default=[], metavar="PATH=SPEC",
                   help="a searched parameter (repeat): LOW..HIGH (ints when both ends and "
                        "the parameter are ints), LOW..HIGH:log, or choices a,b,c")
    p.add_argument("--trials", type=int, required=True, metavar="N", help="trials in all")
    p.add_argument("--batch", type=int, required=True, metavar="B",
                   help="trials run at once, as one sweep")
    p.add_argument("--seeds", type=int, default=None, metavar="S",
                   help="seeds per trial (default: the experiment's)")
    p.add_argument("--metric", default=None, metavar="M",
                   help="the metric (default: the program's progress_metric, else its first "
                        "final metric); a chunk metric counts at the last chunk")
    p.add_argument("--direction", default="maximize", choices=("maximize", "minimize"))
    p.add_argument("--sampler", default="tpe", choices=("tpe", "random", "grid"))
    p.add_argument("--prune", default="none", choices=("halving", "none"),
                   help="halving: successive halving inside each batch (the worst trials' "
                        "learners stop at each rung)")
    p.add_argument("--reduction-factor", type=int, default=None, metavar="ETA",
                   help="halving: 1/ETA of the trials go on at each rung (default 3)")
    p.add_argument("--min-chunks", type=int, default=None, metavar="R",
                   help="halving: chunks of the first rung (default num_chunks // ETA^2)")
    p.add_argument("--confirm-seeds", type=int, default=None, metavar="N",
                   help="fresh seeds of the best trial's confirmation run (default max(S, 8))")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="PATH=VALUE",
                   help="fix a parameter for every trial")
    p.add_argument("--preset", default=None, metavar="NAME", help="a named variant")
    p.add_argument("--seed", type=int, default=0,
                   help="base seed of the search (default 0; the confirmation takes SEED+1)")
    p.add_argument("--out", default=None, help="the search's folder (default "
                   "runs/<name>-tune-<time>)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true", help="continue a stopped search")
    g.add_argument("--overwrite", action="store_true", help="replace an earlier search")
    p.add_argument("--quick", action="store_true", help="the experiment's --quick values")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--checkpoint-every", type=int, default=10, metavar="K",
                   help="chunks between checkpoints (default 10)")
    _add_debug(p, argparse.SUPPRESS)


def _cmd_tune(args) -> int:
    """``vbl tune``: without optuna, one line (exit 1) before anything else."""
    from vbl.engine.config import parse_assignment
    from vbl.engine.tune import require_optuna, tune

    require_optuna()
    experiment = _experiment(args.experiment)
    sets = dict(parse_assignment(s, experiment.default_config) for s in args.sets)
    t0 = time.perf_counter()
    res = tune(experiment, args.space, trials=args.trials, batch=args.batch,
               seeds=args.seeds, metric=args.metric, direction=args.direction,
               sampler=args.sampler, prune=args.prune,
               reduction_factor=args.reduction_factor, min_chunks=args.min_chunks,
               sets=sets, seed=args.seed, confirm_seeds=args.confirm_seeds, out=args.out,
               resume=args.resume, overwrite=args.overwrite, quick=args.quick,
               preset=args.preset, quiet=True if args.quiet else None,
               checkpoint_every=args.checkpoint_every, echo=lambda m: print(m, flush=True),
               command_name=args.experiment)
    sm = res.summary
    s, c = sm["search"], sm["confirmation"]

    def est(iv: dict, fresh: str = "") -> str:
        n = iv["seeds"]
        half = f" ± {iv['ci95']:.3g}" if iv["ci95"] == iv["ci95"] else ""
        return f"{iv['mean']:.4g}{half} ({n} {fresh}seed{'s' * (n != 1)})"

    print(f"best trial {sm['best_trial']}: " + ", ".join(f"{k}={v}" for k, v in
                                                         res.params.items()))
    print(f"  {sm['metric']}: search {est(s)}, confirmation {est(c, 'fresh ')}")
    comp = sm["compute"]
    print(f"  {comp['learner_chunks']:,} learner-chunks of a full grid's "
          f"{comp['full_grid_learner_chunks']:,}; reproduce the confirmation: {c['command']}")
    print(f"{experiment.name}: {time.perf_counter() - t0:.1f} s, report: {res.report}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="vbl", description="vbl: vmapped, sharded, checkpointed "
                     "robot-learning experiments")
    _add_debug(parser)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    p = sub.add_parser("list", help="list registered experiments (* = paper result)")
    _add_debug(p, argparse.SUPPRESS)
    p = sub.add_parser("run", help="run one experiment (a name from `vbl list`, or the path "
                       "of an experiment script)")
    p.add_argument("experiment", help="experiment name, or path/to/script.py")
    _add_run_options(p)
    p = sub.add_parser("merge", help="join the run folders of a run's shards (vbl run "
                       "--shard I/N) into one run folder, as the whole run writes it")
    p.add_argument("folders", nargs="+", metavar="SHARD_DIR", help="the N shards' run folders")
    p.add_argument("--out", required=True, metavar="DIR", help="the merged run folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run folder")
    _add_debug(p, argparse.SUPPRESS)
    p = sub.add_parser("reproduce", help="run every paper experiment and write report.md")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", default=None, help="folder (default runs/reproduce-<time>)")
    p.add_argument("--quiet", action="store_true")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true")
    g.add_argument("--overwrite", action="store_true")
    p.add_argument("--only", action="append", default=None, metavar="NAME",
                   help="run only these paper experiments")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="experiments run in N worker processes at once (default: one per "
                        "CPU core; 1 = one after the other in this process, with progress "
                        "bars)")
    _add_debug(p, argparse.SUPPRESS)
    p = sub.add_parser("report", help="one Markdown table of the paper's numbers beside "
                       "those of finished run folders, with the commands that regenerate them")
    p.add_argument("folders", nargs="+", metavar="RUN_DIR", help="run folders (vbl run --out)")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="write the table to FILE (links relative to its folder) instead of "
                        "printing it")
    p.add_argument("--seeds", type=int, default=None, metavar="K",
                   help="rebuild every run from its first K seeds (what a K-seed run gives) "
                        "and add each run's report section, its claims, at K seeds")
    _add_debug(p, argparse.SUPPRESS)
    p = sub.add_parser("bench", help="run the benchmarks (benchmarks/*.py of the source tree)")
    p.add_argument("--quick", action="store_true", help="small sizes")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="results folder (default ./vbl-bench; --out benchmarks/results "
                        "updates the committed results)")
    p.add_argument("names", nargs="*", help="benchmark names (default: all)")
    _add_debug(p, argparse.SUPPRESS)
    _add_render(sub)
    _add_data_commands(sub)
    _add_tune(sub)
    p = sub.add_parser("params", help="the parameter table of an experiment (Markdown)")
    p.add_argument("experiment", help="experiment name, or path/to/script.py")
    _add_debug(p, argparse.SUPPRESS)
    return parser


def _error(msg: str, code: int) -> int:
    from vbl.engine.errors import final_line

    msg = "; ".join(x.strip() for x in str(msg).splitlines() if x.strip())
    final_line(msg, code)
    return code


def _stdout_gone() -> int:
    """stdout's reader left (``vbl params X | head``): no message, nothing more written to
    stdout, exit 141 (128 + SIGPIPE, what a shell reports for a command killed by it)."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError):
        pass
    return 141


def _cmd_list() -> int:
    from vbl.engine import all_experiments, discover
    from vbl.engine.registry import import_errors

    discover()
    exps = all_experiments()
    width = max([len(n) for n in exps] + [4])
    for name, e in exps.items():
        print(f"{'*' if e.paper_result else ' '} {name:<{width}}  {e.description}")
    for path, err in import_errors().items():
        print(f"! {Path(path).stem:<{width}}  failed to import: {err}", file=sys.stderr)
    if not exps:
        from vbl.engine.registry import experiment_dirs

        print(f"(no experiments found in {', '.join(map(str, experiment_dirs()))}; the built-in "
              f"ones are in the source tree's experiments/: run vbl from the source tree or "
              f"install it with pip install -e .; run a script of your own with vbl run "
              f"path/to/script.py)")
    return 0


def _run(experiment, args) -> int:
    from vbl.engine.config import parse_assignment, parse_sweep
    from vbl.engine.runner import describe_sweep, run_experiment
    from vbl.engine.sweep import parse_shard
    from vbl.params import ParamError

    cfg = experiment.default_config
    sets = dict(parse_assignment(s, cfg) for s in args.sets)
    sweep: dict = {}
    for text in args.sweep:
        path, values = parse_sweep(text, cfg)
        if path in sweep:
            raise ParamError(f"--sweep {path} is given twice; give all its values in one "
                             f"--sweep {path}=V1,V2,...")
        sweep[path] = values
    shard = parse_shard(args.shard) if args.shard is not None else None
    import jax

    primary = jax.process_index() == 0
    if primary:
        points, seeds, text = describe_sweep(experiment, sets, sweep, args.seeds, args.quick,
                                             args.preset)
        if shard is not None and shard.count <= points * seeds:
            lo, hi = shard.learner_range(points * seeds)
            part = f"learner {lo}" if hi - lo == 1 else f"learners {lo}-{hi - 1}"
            text += (f"\n  shard {shard}: {part} of 0-{points * seeds - 1} "
                     f"(learner = point x {seeds} + seed)")
        print(text, flush=True)
    t0 = time.perf_counter()
    result = run_experiment(experiment, sets=sets, sweep=sweep, seeds=args.seeds,
                            base_seed=args.seed, out=args.out, resume=args.resume,
                            overwrite=args.overwrite, quick=args.quick,
                            quiet=True if args.quiet else None,
                            checkpoint_every=args.checkpoint_every,
                            learner_batch=args.learner_batch,
                            memory_check=not args.no_memory_check, preset=args.preset,
                            shard=shard, tensorboard=args.tensorboard)
    if primary and shard is not None:
        n = result.summary["learners"]
        print(f"{experiment.name}: shard {shard} ({n} learner{'s' * (n != 1)}) done "
              f"in {time.perf_counter() - t0:.1f} s, in {result.out_dir}; when all "
              f"{shard.count} are done: vbl merge SHARD_DIR... --out DIR")
    elif primary:
        _headline(experiment, result, t0)
    return 0


def _headline(experiment, result, t0: float) -> None:
    """Print the headline table of a run (or merge) that wrote its report.md."""
    from vbl.engine.report import headline_table

    print(headline_table(result, experiment))
    print(f"\n{experiment.name}: {time.perf_counter() - t0:.1f} s, results in "
          f"{result.out_dir} (report: report.md, every metric: summary.json)")


def _cmd_merge(args) -> int:
    from vbl.engine.merge import merge_runs

    t0 = time.perf_counter()
    experiment, result = merge_runs(args.folders, args.out, overwrite=args.overwrite)
    _headline(experiment, result, t0)
    return 0


def _experiment(name: str):
    """A registered experiment by name, or the one a script file registers (a path)."""
    from vbl.engine import get
    from vbl.engine.registry import is_script_path, load_experiment_file

    return load_experiment_file(name) if is_script_path(name) else get(name)


def _check_out_early(args) -> None:
    """A taken ``--out`` is refused before the experiment (and JAX) is imported; the run
    checks it again (a multi-process run's other processes find the folder made)."""
    from vbl.engine.runfolder import check_new_folder

    single = not (args.coordinator or os.environ.get("VBL_COORDINATOR") or args.num_processes)
    if args.out is not None and single:
        check_new_folder(Path(args.out), resume=args.resume, overwrite=args.overwrite)


def _init_distributed(args) -> None:
    from vbl.engine.distributed import initialize

    initialize(args.coordinator, args.num_processes, args.process_id)


def _cmd_bench(args) -> int:
    from vbl.engine.bench import run_benchmarks

    failed = run_benchmarks(args.names, args.out, args.quick)
    if failed:
        return _error(f"benchmark(s) failed: {failed}", 1)
    return 0


def _cmd_report(args) -> int:
    from vbl.engine.errors import EngineError
    from vbl.engine.rebuild import results_table

    out = Path(args.out) if args.out is not None else None
    base = out.absolute().parent if out is not None else None
    try:
        with contextlib.redirect_stdout(sys.stderr):  # what imported scripts print stays apart
            if args.seeds is None:
                table = results_table(args.folders, link_base=base)
            else:
                from vbl.engine.seed_subsets import seeds_report

                table = seeds_report(args.folders, args.seeds, link_base=base)
    except EngineError as e:  # a bad folder: the exit code of render, export and plot
        return _error(str(e), 2)
    if out is None:
        print(table, end="")
        return 0
    try:
        out.write_text(table)
    except OSError as e:
        raise EngineError(f"cannot write {out}: {e.strerror or e}") from e
    print(f"results table: {out}")
    return 0


def _cmd_render(args) -> int:
    """``vbl render``: bad input (not a finished run folder, a policy that cannot be
    rebuilt, a bad extension or count) is one line and exit 2."""
    from vbl.engine.errors import EngineError
    from vbl.params import validate
    from vbl.programs.video import VideoParams, render_run

    sets = {k: v for k, v in (("height", args.height), ("max_steps", args.max_steps))
            if v is not None}
    vp = validate(VideoParams().replace(**sets))  # a ParamError exits 2
    try:
        v = render_run(args.folder, args.out, args.episodes, args.policy, args.point,
                       args.seed, args.key, vp)
    except EngineError as e:
        return _error(str(e), 2)
    print(f"video: {args.out} ({v.frames} frames, {v.width} x {v.height} px; {v.title})")
    return 0


def _cmd_export(args) -> int:
    """``vbl export``: a folder that is not a run folder is bad input (one line, exit 2)."""
    from vbl.engine.errors import EngineError
    from vbl.engine.export import export_run, read_run

    try:
        run = read_run(args.folder)
    except EngineError as e:
        return _error(str(e), 2)
    out, rows = export_run(run, args.out, args.format, final=args.final)
    print(f"table: {out} ({rows:,} rows)")
    return 0


def _cmd_plot(args) -> int:
    """``vbl plot``: a folder that is not a run folder is bad input (one line, exit 2)."""
    from vbl.engine.errors import EngineError
    from vbl.engine.export import read_run
    from vbl.engine.plots import plot_sweep

    try:
        run = read_run(args.folder)
    except EngineError as e:
        return _error(str(e), 2)
    print(f"plot: {plot_sweep(run, args.x, args.y, args.out)}")
    return 0


def _dispatch(args) -> int:
    if args.command == "list":
        return _cmd_list()
    if args.command == "params":
        from vbl.engine.paramdoc import experiment_page

        print(experiment_page(_experiment(args.experiment)))
        return 0
    if args.command == "run":
        _init_distributed(args)
        return _run(_experiment(args.experiment), args)
    if args.command == "reproduce":
        from vbl.engine.reproduce import paper_experiments, reproduce

        out = Path(args.out or f"runs/reproduce-{time.strftime('%Y%m%d-%H%M%S')}")
        if not paper_experiments():
            return _error("no paper experiments are registered (Experiment.paper_result)", 1)
        if args.jobs is not None and args.jobs < 1:
            return _error(f"--jobs must be >= 1, got {args.jobs}", 2)
        report, ok = reproduce(out, quick=args.quick, quiet=True if args.quiet else None,
                               resume=args.resume, overwrite=args.overwrite, names=args.only,
                               jobs=args.jobs)
        print(f"report: {report}", flush=True)
        return 0 if ok else _error(f"some experiments failed; see {report}", 1)
    commands = {"merge": _cmd_merge, "bench": _cmd_bench, "report": _cmd_report,
                "render": _cmd_render, "export": _cmd_export, "plot": _cmd_plot,
                "tune": _cmd_tune}
    return commands[args.command](args)


def _guarded(fn, *a, debug: bool = False) -> int:
    """Run ``fn``; every failure ends in one ``vbl: error: ...`` line and a non-zero exit
    (with ``debug`` or ``VBL_DEBUG=1`` the traceback comes first)."""
    import traceback

    from vbl.engine.errors import EngineError, debug_requested, one_line, stop_code, stop_message

    debug = debug or debug_requested()
    try:
        code = fn(*a)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return code
    except KeyboardInterrupt as e:  # SIGINT, or SIGTERM (Terminated)
        # a stop can leave an asynchronous checkpoint's coroutine unstarted; Python's
        # warning when it is collected would follow the one error line
        warnings.filterwarnings("ignore", message="coroutine .* was never awaited",
                                category=RuntimeWarning)
        return _error(stop_message(e), stop_code(e))
    except BrokenPipeError as e:
        if _is_stdout_pipe(e):
            return _stdout_gone()
        return _error(one_line(e), 1)
    except Exception as e:  # noqa: BLE001 - the command's last word on any failure
        if debug:
            traceback.print_exc()
        if isinstance(e, EngineError):
            return _error(str(e), 1)
        from vbl.params import ParamError  # imports JAX: only for an error that may be one

        if isinstance(e, ParamError):
            return _error(str(e), 2)
        return _error(one_line(e), 1)


def _is_stdout_pipe(e: BrokenPipeError) -> bool:
    """Whether the broken pipe is stdout's: a write to a pipe names no file (a file
    operation that fails with EPIPE does)."""
    return e.filename is None


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``vbl`` console script; returns the exit code."""
    from vbl.engine.errors import new_command

    new_command()
    args = build_parser().parse_args(argv)

    def go() -> int:
        if args.command == "run":
            _check_out_early(args)  # before JAX loads
        quiet_xla()
        return _dispatch(args)

    return _guarded(go, debug=args.debug)


def console_main() -> int:
    """The installed ``vbl`` command: :func:`use_all_cores`, then :func:`main`."""
    from vbl.engine.errors import install_stop_handlers

    install_stop_handlers()  # SIGINT and SIGTERM stop it with one line
    use_all_cores()
    quiet_process(sys.argv[1:])
    return end_process(main(), sys.argv[1:])


def main_for(experiment, argv: list[str] | None = None) -> None:
    """``python experiments/x.py [run options]``: the same as ``vbl run x [run options]``."""
    parser = _Parser(prog=f"python {sys.argv[0]}",
                     description=f"{experiment.name}: {experiment.description}")
    _add_run_options(parser)
    args = parser.parse_args(argv)
    if argv is None:
        from vbl.engine.errors import install_stop_handlers

        rerun_with_quiet_xla()
        install_stop_handlers()
    use_all_cores()
    quiet_process(sys.argv[1:] if argv is None else argv)

    def go() -> int:
        _check_out_early(args)  # before JAX loads
        quiet_xla()
        _init_distributed(args)
        return _run(experiment, args)

    code = _guarded(go, debug=getattr(args, "debug", False))
    sys.exit(end_process(code, sys.argv[1:] if argv is None else argv, process=argv is None))


if __name__ == "__main__":
    sys.exit(console_main())
