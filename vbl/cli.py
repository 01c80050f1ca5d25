"""The ``vbl`` command: list, run, reproduce, bench, params (see docs/engine.md)."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

__all__ = ["main", "main_for", "build_parser"]


def _add_run_options(p: argparse.ArgumentParser) -> None:
    from vbl.engine.runner import DEFAULT_CHECKPOINT_EVERY, DEFAULT_LEARNER_BATCH

    p.add_argument("--set", dest="sets", action="append", default=[], metavar="PATH=VALUE",
                   help="override a parameter, e.g. --set agent.learning_rate=0.1")
    p.add_argument("--sweep", action="append", default=[], metavar="PATH=V1,V2,...",
                   help="sweep a parameter over values (repeat for a grid)")
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
    p.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="multi-process coordinator (or VBL_COORDINATOR)")
    p.add_argument("--num-processes", type=int, default=None,
                   help="number of processes (or VBL_NUM_PROCESSES)")
    p.add_argument("--process-id", type=int, default=None,
                   help="this process's id (or VBL_PROCESS_ID)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vbl", description="vbl: vmapped, sharded, "
                                     "checkpointed robot-learning experiments")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="list registered experiments (* = paper result)")
    p = sub.add_parser("run", help="run one experiment")
    p.add_argument("experiment")
    _add_run_options(p)
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
    p = sub.add_parser("bench", help="run benchmarks/*.py")
    p.add_argument("--quick", action="store_true")
    p.add_argument("names", nargs="*", help="benchmark names (default: all)")
    p = sub.add_parser("params", help="the parameter table of an experiment (Markdown)")
    p.add_argument("experiment")
    return parser


def _error(msg: str, code: int) -> int:
    print(f"vbl: error: {msg}", file=sys.stderr)
    return code


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
        print("(no experiments found)")
    return 0


def _run(experiment, args) -> int:
    from vbl.engine.config import parse_assignment, parse_sweep
    from vbl.engine.report import default_section
    from vbl.engine.runner import run_experiment

    cfg = experiment.default_config
    sets = dict(parse_assignment(s, cfg) for s in args.sets)
    sweep = dict(parse_sweep(s, cfg) for s in args.sweep)
    t0 = time.perf_counter()
    result = run_experiment(experiment, sets=sets, sweep=sweep, seeds=args.seeds,
                            base_seed=args.seed, out=args.out, resume=args.resume,
                            overwrite=args.overwrite, quick=args.quick,
                            quiet=True if args.quiet else None,
                            checkpoint_every=args.checkpoint_every,
                            learner_batch=args.learner_batch)
    import jax

    if jax.process_index() == 0:
        print(default_section(result).markdown)
        print(f"\n{experiment.name}: {time.perf_counter() - t0:.1f} s, results in "
              f"{result.out_dir}")
    return 0


def _init_distributed(args) -> None:
    from vbl.engine.distributed import initialize

    initialize(args.coordinator, args.num_processes, args.process_id)


def _cmd_bench(args) -> int:
    import vbl

    bench_dir = Path(vbl.__file__).resolve().parents[1] / "benchmarks"
    scripts = sorted(p for p in bench_dir.glob("*.py") if not p.name.startswith("_"))
    if args.names:
        known = {p.stem: p for p in scripts}
        bad = [n for n in args.names if n not in known]
        if bad:
            return _error(f"unknown benchmark(s) {bad}; valid: {sorted(known)}", 2)
        scripts = [known[n] for n in args.names]
    failed = []
    for s in scripts:
        print(f"== {s.stem}", flush=True)
        cmd = [sys.executable, str(s)] + (["--quick"] if args.quick else [])
        if subprocess.run(cmd, cwd=bench_dir.parent).returncode != 0:
            failed.append(s.stem)
    if failed:
        return _error(f"benchmark(s) failed: {failed}", 1)
    return 0


def _dispatch(args) -> int:
    from vbl.engine import get

    if args.command == "list":
        return _cmd_list()
    if args.command == "params":
        from vbl.params import markdown_table

        print(markdown_table(get(args.experiment).default_config))
        return 0
    if args.command == "run":
        _init_distributed(args)
        return _run(get(args.experiment), args)
    if args.command == "reproduce":
        from vbl.engine.report import paper_experiments, reproduce

        out = Path(args.out or f"runs/reproduce-{time.strftime('%Y%m%d-%H%M%S')}")
        if not paper_experiments():
            return _error("no paper experiments are registered (Experiment.paper_result)", 1)
        if args.jobs is not None and args.jobs < 1:
            return _error(f"--jobs must be >= 1, got {args.jobs}", 2)
        report, ok = reproduce(out, quick=args.quick, quiet=True if args.quiet else None,
                               resume=args.resume, overwrite=args.overwrite, names=args.only,
                               jobs=args.jobs)
        print(f"report: {report}")
        return 0 if ok else _error(f"some experiments failed; see {report}", 1)
    if args.command == "bench":
        return _cmd_bench(args)
    raise AssertionError(args.command)


def _guarded(fn, *a) -> int:
    from vbl.engine.config import EngineError
    from vbl.params import ParamError

    try:
        return fn(*a)
    except ParamError as e:
        return _error(str(e), 2)
    except EngineError as e:
        return _error(str(e), 1)
    except KeyboardInterrupt:
        return _error("interrupted", 130)


def use_all_cores() -> int:
    """Expose CPU cores as JAX host devices if asked (call before JAX's first computation).

    ``VBL_HOST_DEVICES=N`` (N > 1) sets ``--xla_force_host_platform_device_count=N``: the
    engine then shards the learner axis over N devices (results do not depend on N), and
    the env benchmark runs 2.3x faster on 2 devices than on one on a 2-core machine. Off
    by default (one device) until multi-device runs of every experiment are measured; the
    hang first seen there (concurrent batched SVDs, see ``vbl.sysid.linalg``) is fixed.
    An ``XLA_FLAGS`` that already sets the count wins. Returns the count set (0 when
    nothing was changed).
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" in flags:
        return 0
    raw = os.environ.get("VBL_HOST_DEVICES", "1") or "1"
    try:
        n = int(raw)
    except ValueError:
        raise SystemExit(f"vbl: error: VBL_HOST_DEVICES={raw!r} must be an integer >= 1"
                         ) from None
    if n < 1:
        raise SystemExit(f"vbl: error: VBL_HOST_DEVICES={raw!r} must be an integer >= 1")
    if n == 1:
        return 0
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={n}".strip()
    return n


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``vbl`` console script; returns the exit code."""
    args = build_parser().parse_args(argv)
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
    return _guarded(_dispatch, args)


def console_main() -> int:
    """The installed ``vbl`` command: :func:`use_all_cores`, then :func:`main`."""
    use_all_cores()
    return main()


def main_for(experiment, argv: list[str] | None = None) -> None:
    """``python experiments/x.py [run options]``: the same as ``vbl run x [run options]``."""
    parser = argparse.ArgumentParser(prog=f"python {sys.argv[0]}",
                                     description=f"{experiment.name}: {experiment.description}")
    _add_run_options(parser)
    args = parser.parse_args(argv)

    def go() -> int:
        _init_distributed(args)
        return _run(experiment, args)

    sys.exit(_guarded(go))


if __name__ == "__main__":
    sys.exit(main())
