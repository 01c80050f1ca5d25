"""Compile time of every program ``vbl reproduce`` compiles.

For each run of the full ``vbl reproduce`` (every paper experiment's default config and
its published presets, full-scale plans as ``vbl run`` makes them; ``--quick`` runs the
same programs, the presets excepted) and each of its groups (one compilation each), the
program's ``init``, ``step`` and ``final`` are lowered and compiled the way the engine
compiles them
(``jit(shard_map(vmap(...)))`` with the learner axis split over the devices, inside
:func:`vbl.engine.jax_setup.engine_precision`), with the persistent compilation cache off.
``trace`` is Python tracing + lowering to StableHLO, ``compile`` XLA's compilation; their
sum is what a cold run waits for, per program. Both are reported as process CPU time (the
target's measure: it stretches less with other jobs' load than wall time; XLA's CPU
compiler runs part of its work on a thread pool, so on a quiet machine the CPU time is up
to about 1.6x the wall time a user waits) and as wall time. ``init`` runs once to give
``step`` its carry (its run time is not counted). A program whose StableHLO equals an
earlier row's is marked ``shared``: the persistent compilation cache that a reproduce's
workers share compiles it once. The ``before`` column is the committed measurement of the
code before the compile-cost work (``compile_time_before.json``, the same 2-core machine
type, quiet), matched by experiment, group and function.

``--quick`` measures the programs of ``vbl reproduce --quick`` instead: its runs at their
quick scale (a quick config may change a static size, so a quick program can be smaller
than its full-scale row), written to ``compile_time_quick.{json,md}``.

Usage::

    python benchmarks/compile_time.py                        # every reproduce run
    python benchmarks/compile_time.py --quick                # the quick reproduce's programs
    python benchmarks/compile_time.py --runs table2_shoot_pass
    python benchmarks/compile_time.py --runs table2_shoot_pass --merge
Writes benchmarks/results/compile_time.{json,md} (``--out`` elsewhere). ``--merge`` keeps
the rows of the other runs from the existing JSON and replaces those measured now;
each row records the load average when it was measured (rows of different runs compare
only roughly: compile CPU time stretches with the load).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.devices import force_host_devices  # noqa: E402

DEVICES = force_host_devices()  # before jax is imported: --devices N, else every core
os.environ["VBL_JAX_CACHE"] = "0"  # time real compilations

import jax  # noqa: E402

import vbl  # noqa: E402,F401
from benchmarks.hardware import hardware_info, write_results  # noqa: E402
from vbl.engine import registry  # noqa: E402
from vbl.engine.jax_setup import engine_precision  # noqa: E402
from vbl.engine.reproduce import Job, paper_experiments, reproduce_jobs  # noqa: E402
from vbl.engine.runner import _compiled, resolve  # noqa: E402
from vbl.engine.sharding import learner_sharding, put  # noqa: E402
from vbl.engine.sweep import make_plan  # noqa: E402
from vbl.params import get_path  # noqa: E402

MAX_COMPILE_S = 60.0  #: target: trace + compile of any one program on the 2-core machine


def _timed(fn, *args) -> tuple[dict, object]:
    """Wall and process CPU seconds of tracing + lowering (``trace``) and of XLA's
    compilation (``compile``) of the jitted ``fn`` at ``args``, the compiled function, and
    a hash of the lowered StableHLO (equal hashes: one compilation in a shared cache)."""
    w0, c0 = time.perf_counter(), time.process_time()
    lowered = fn.lower(*args)
    w1, c1 = time.perf_counter(), time.process_time()
    compiled = lowered.compile()
    w2, c2 = time.perf_counter(), time.process_time()
    hlo = hashlib.sha256(lowered.as_text().encode()).hexdigest()[:16]
    return dict(trace_s=w1 - w0, compile_s=w2 - w1, trace_cpu_s=c1 - c0,
                compile_cpu_s=c2 - c1, hlo=hlo), compiled


def in_quick(exp, preset: str | None, static_values: dict) -> bool:
    """Whether ``vbl reproduce --quick`` compiles the group of ``static_values`` (its
    static swept paths) of a reproduce run: a default run kept in the quick reproduce,
    whose quick config or sweep holds each of those values."""
    if preset is not None or not exp.in_quick_reproduce:
        return False
    config, sweep, *_ = resolve(exp, quick=True)
    return all(v in sweep[p] if p in sweep else get_path(config, p) == v
               for p, v in static_values.items())


def time_run(job: Job, quick: bool = False) -> list[dict]:
    """One row per (group, function) of the plan of ``job`` (a reproduce run; ``quick``:
    its quick-scale plan); ``quick`` in a row: whether the quick reproduce compiles that
    group (:func:`in_quick`), at its own scale."""
    exp = registry.get(job.name)
    config, sweep, seeds, _ = resolve(exp, preset=job.preset, quick=quick)
    plan = make_plan(exp, config, sweep, seeds)
    if plan is None:
        return []
    sharding = learner_sharding()
    rows = []

    def row(head, function, times):
        rows.append(dict(head, function=function, load=os.getloadavg()[0], **times))
        print(json.dumps(rows[-1]), flush=True)

    with engine_precision():
        for group in plan.groups:
            prog, n = group.program, group.num_learners
            init_fn, step_fn, final_fn, begin_fn = _compiled(prog, sharding)
            reps = len(group.point_ids)
            keys = put(np.tile(plan.init_keys, (reps, 1)), sharding)
            final_keys = put(np.tile(plan.final_keys, (reps, 1)), sharding)
            cfgs = put(group.configs, sharding)
            head = dict(run=job.folder, experiment=job.name, preset=job.preset,
                        group=group.index, learners=n,
                        quick=quick or in_quick(exp, job.preset, group.static_values))
            times, init_c = _timed(init_fn, keys, cfgs)
            row(head, "init", times)
            carry = jax.block_until_ready(init_c(keys, cfgs))
            row(head, "step", _timed(step_fn, carry, cfgs)[0])
            if begin_fn is not None:
                row(head, "begin_final", _timed(begin_fn, carry, cfgs, final_keys)[0])
            if final_fn is not None:
                row(head, "final", _timed(final_fn, carry, cfgs, final_keys)[0])
    return rows


def _total(r: dict) -> float:
    return r["trace_cpu_s"] + r["compile_cpu_s"]


def _scope(quick: bool, b_where: str, before: dict | None) -> str:
    """What the table's rows are, for the header of :func:`markdown`; a ``before`` JSON
    says what it measured in its ``note`` (the code and commit it compares with), else the
    default comparison of the table is meant."""
    what = (before or {}).get("note", (
        "the same program with the tabular learner's final evaluation as a program of its "
        "own (commit 06b55b1") if quick else (
        "the same program before the compile-cost work (commit b22967f"))
    if quick:
        return ("Every program of `vbl reproduce --quick` (its quick-scale plans), persistent "
                "compilation cache off. `before`: " + (
                    f"{what}, measured {b_where}; `-`: a program that did not exist then)."
                    if before else "none given."))
    return ("Every program of the full `vbl reproduce` (full-scale plans; `quick`: "
            "`vbl reproduce --quick` compiles the group too, at its own scale, which "
            "`compile_time_quick.md` measures), persistent compilation cache off. `before`: "
            f"{what}, measured {b_where}; another machine type when its CPU differs, so "
            "compare the totals roughly; `-`: a program that did not exist then).")


def markdown(result: dict, cmd: str, before: dict | None) -> str:
    hw = result["hardware"]
    rows = result["rows"]
    seen: set[str] = set()
    for r in rows:  # the first row of each StableHLO compiles; later equal ones share it
        r["shared"] = r["hlo"] in seen
        seen.add(r["hlo"])
    b_rows = before["rows"] if before else []
    old = {(b["experiment"], b["group"], b["function"]): _total(b) for b in b_rows}
    b_hw = before["hardware"] if before else {}
    b_where = (f"on a {b_hw.get('cores')}-core {b_hw.get('cpu')}, load average "
               f"{b_hw.get('load_average', float('nan')):.1f}" if before else "none given")
    worst = max(rows, key=_total)
    merged = " (rows of several runs: the load column is each row's)" if result.get(
        "merged") else ""
    lines = [f"Compile time ({hw['cpu']}, {hw['cores']} cores, {len(hw['devices'])} "
             f"device(s), jax {hw['jax']}, load average {hw['load_average']:.1f} at the start "
             f"and {result['load_end']:.1f} at the end{merged}; `{cmd}`). "
             f"{_scope(bool(result.get('quick')), b_where, before)} `shared`: its "
             "StableHLO "
             "equals an earlier row's, so a reproduce compiles it once.", "",
             "| run | group | function | learners | trace CPU s | compile CPU s | "
             "total CPU s | before: total CPU s | total wall s | load | shared | quick |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---|---|"]
    for r in rows:
        prev = old.get((r["experiment"], r["group"], r["function"])) if not r.get(
            "preset") else None
        lines.append(f"| {r['run']} | {r['group']} | {r['function']} | {r['learners']} | "
                     f"{r['trace_cpu_s']:.1f} | {r['compile_cpu_s']:.1f} | {_total(r):.1f} | "
                     f"{'-' if prev is None else f'{prev:.1f}'} | "
                     f"{r['trace_s'] + r['compile_s']:.1f} | {r['load']:.1f} | "
                     f"{'yes' if r['shared'] else ''} | {'yes' if r['quick'] else ''} |")
    own = [r for r in rows if not r["shared"]]
    walls = [r["trace_s"] + r["compile_s"] for r in rows]
    which = "`vbl reproduce --quick`" if result.get("quick") else "full reproduce"
    lines += ["", f"Compiled by a cold {which}: {len(own)} programs, "
              f"{sum(map(_total, own)):.0f} CPU s" + (
                  f"; before: {len(b_rows)} programs"
                  f"{'' if result.get('quick') else ' (defaults only)'}, "
                  f"{sum(map(_total, b_rows)):.0f} CPU s." if before else "."), "",
              f"Target: every program <= {MAX_COMPILE_S:.0f} s (trace + compile, CPU time): "
              f"{'met' if _total(worst) <= MAX_COMPILE_S else 'not met'}; the longest is "
              f"{worst['run']} {worst['function']}, {_total(worst):.1f} CPU s; the longest "
              f"wall time is {max(walls):.1f} s. XLA's CPU compiler runs part of its work on a "
              "thread pool, so CPU time exceeds wall time on a quiet machine; on a shared "
              "machine the wall time stretches with the load, and the CPU time too, less "
              "(contention for caches and memory): compare rows of one run.", ""]
    return "\n".join(lines)


def main(argv=None):
    registry.discover()
    every = [j.folder for j in reproduce_jobs(paper_experiments())]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", nargs="*", choices=every,
                    help="reproduce runs to measure (default: every one)")
    ap.add_argument("--devices", type=int, default=DEVICES,
                    help="JAX host devices (default: every usable core)")
    ap.add_argument("--quick", action="store_true",
                    help="the programs of vbl reproduce --quick, at their quick scale")
    ap.add_argument("--out", help="results path without suffix (default: benchmarks/results/"
                    "compile_time, with --quick compile_time_quick)")
    ap.add_argument("--before", help="the measurement to compare with (JSON of this "
                    "benchmark; default: benchmarks/results/compile_time_before.json, with "
                    "--quick compile_time_quick_before.json)")
    ap.add_argument("--merge", action="store_true",
                    help="keep the other runs' rows of the existing JSON at --out")
    ap.add_argument("--rebuild", action="store_true",
                    help="measure nothing: the tables again from the JSON at --out")
    args = ap.parse_args(argv)
    jobs = reproduce_jobs(paper_experiments(), quick=args.quick)
    folders = [j.folder for j in jobs]
    runs = folders if args.runs is None else args.runs
    if not set(runs) <= set(folders):
        ap.error(f"--runs {sorted(set(runs) - set(folders))}: not in vbl reproduce --quick; "
                 f"choose from {folders}")
    out = pathlib.Path(args.out or ROOT / "benchmarks" / "results" / (
        "compile_time_quick" if args.quick else "compile_time"))

    def before_of(result: dict) -> dict | None:
        path = pathlib.Path(args.before or ROOT / "benchmarks" / "results" / (
            "compile_time_quick_before.json" if result.get("quick") else
            "compile_time_before.json"))
        return json.loads(path.read_text()) if path.exists() else None

    if args.rebuild:
        result = json.loads(out.with_suffix(".json").read_text())
        text = markdown(result, result.get("command", "python benchmarks/compile_time.py"),
                        before_of(result))
        write_results(out, result, text)
        print(text)
        return
    result = dict(benchmark="compile_time", hardware=hardware_info(), rows=[],
                  target_s=MAX_COMPILE_S, quick=args.quick)
    fresh = {j.folder: time_run(j, args.quick) for j in jobs if j.folder in runs}
    old = (json.loads(out.with_suffix(".json").read_text())["rows"]
           if args.merge and out.with_suffix(".json").exists() else [])
    kept = [r for r in old if r.get("run") in folders and r["run"] not in fresh]
    result["merged"] = bool(kept)
    by_run: dict[str, list[dict]] = {}
    for r in kept + [r for rows in fresh.values() for r in rows]:
        by_run.setdefault(r["run"], []).append(r)
    result["rows"] = [r for f in folders for r in by_run.get(f, [])]
    result["load_end"] = os.getloadavg()[0]
    result["command"] = cmd = "python benchmarks/compile_time.py" + (
        " --quick" if args.quick else "") + (
        " --runs " + " ".join(runs) if runs != folders else "") + (
        " --merge" if args.merge else "") + (
        f" --before {args.before}" if args.before else "")
    text = markdown(result, cmd, before_of(result))
    write_results(out, result, text)
    print(text)


if __name__ == "__main__":
    main()
