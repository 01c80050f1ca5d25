"""Compile time of every program a full-scale ``vbl run`` compiles.

For each registered experiment (default config, default sweep and seeds, as ``vbl run``
plans it) and each of its groups (one compilation each), the program's ``init``, ``step``
and ``final`` are lowered and compiled the way the engine compiles them
(``jit(shard_map(vmap(...)))`` with the learner axis split over the devices, inside
:func:`vbl.engine.jax_setup.engine_precision`), with the persistent compilation cache off.
``trace`` is Python tracing + lowering to StableHLO, ``compile`` XLA's compilation; their
sum is what a cold run waits for, per program. Both are reported as process CPU time (the
target's measure: it stretches less with other jobs' load than wall time; XLA's CPU
compiler runs part of its work on a thread pool, so on a quiet machine the CPU time is up
to about 1.6x the wall time a user waits) and as wall time. ``init`` runs once to give
``step`` its carry (its run time is not counted).

Usage::

    python benchmarks/compile_time.py                        # every experiment
    python benchmarks/compile_time.py --experiments table2_shoot_pass
    python benchmarks/compile_time.py --experiments table2_shoot_pass --merge
Writes benchmarks/results/compile_time.{json,md} (``--out`` elsewhere). ``--merge`` keeps
the rows of the other experiments from the existing JSON and replaces those measured now;
each row records the load average when it was measured (rows of different runs compare
only roughly: compile CPU time stretches with the load).
"""

from __future__ import annotations

import argparse
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
from vbl.engine.runner import _compiled, resolve  # noqa: E402
from vbl.engine.sharding import learner_sharding, put  # noqa: E402
from vbl.engine.sweep import make_plan  # noqa: E402

MAX_COMPILE_S = 60.0  #: target: trace + compile of any one program on the 2-core machine


def _timed(fn, *args) -> tuple[dict, object]:
    """Wall and process CPU seconds of tracing + lowering (``trace``) and of XLA's
    compilation (``compile``) of the jitted ``fn`` at ``args``, and the compiled function."""
    w0, c0 = time.perf_counter(), time.process_time()
    lowered = fn.lower(*args)
    w1, c1 = time.perf_counter(), time.process_time()
    compiled = lowered.compile()
    w2, c2 = time.perf_counter(), time.process_time()
    return dict(trace_s=w1 - w0, compile_s=w2 - w1, trace_cpu_s=c1 - c0,
                compile_cpu_s=c2 - c1), compiled


def time_experiment(name: str) -> list[dict]:
    """One row per (group, function) of ``name``'s full-scale plan."""
    exp = registry.get(name)
    config, sweep, seeds, _ = resolve(exp)
    plan = make_plan(exp, config, sweep, seeds)
    if plan is None:
        return []
    sharding = learner_sharding()
    rows = []
    with engine_precision():
        for group in plan.groups:
            prog, n = group.program, group.num_learners
            init_fn, step_fn, final_fn = _compiled(prog, sharding)
            reps = len(group.point_ids)
            keys = put(np.tile(plan.init_keys, (reps, 1)), sharding)
            final_keys = put(np.tile(plan.final_keys, (reps, 1)), sharding)
            cfgs = put(group.configs, sharding)
            head = dict(experiment=name, group=group.index, learners=n)
            times, init_c = _timed(init_fn, keys, cfgs)
            times["load"] = os.getloadavg()[0]
            rows.append(dict(head, function="init", **times))
            print(json.dumps(rows[-1]), flush=True)
            carry = jax.block_until_ready(init_c(keys, cfgs))
            times, _ = _timed(step_fn, carry, cfgs)
            times["load"] = os.getloadavg()[0]
            rows.append(dict(head, function="step", **times))
            print(json.dumps(rows[-1]), flush=True)
            if final_fn is not None:
                times, _ = _timed(final_fn, carry, cfgs, final_keys)
                times["load"] = os.getloadavg()[0]
                rows.append(dict(head, function="final", **times))
                print(json.dumps(rows[-1]), flush=True)
    return rows


def markdown(result: dict, cmd: str) -> str:
    hw = result["hardware"]
    worst = max(result["rows"], key=lambda r: r["trace_cpu_s"] + r["compile_cpu_s"])
    total = worst["trace_cpu_s"] + worst["compile_cpu_s"]
    merged = " (rows of several runs: the load column is each row's)" if result.get(
        "merged") else ""
    lines = [f"Compile time ({hw['cpu']}, {hw['cores']} cores, {len(hw['devices'])} "
             f"device(s), jax {hw['jax']}, load average {hw['load_average']:.1f} at the start "
             f"and {result['load_end']:.1f} at the end{merged}; `{cmd}`). Full-scale default "
             "plans, persistent compilation cache off.", "",
             "| experiment | group | function | learners | trace CPU s | compile CPU s | "
             "total CPU s | total wall s | load |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|"]
    for r in result["rows"]:
        load = f"{r['load']:.1f}" if "load" in r else "-"
        lines.append(f"| {r['experiment']} | {r['group']} | {r['function']} | "
                     f"{r['learners']} | {r['trace_cpu_s']:.1f} | {r['compile_cpu_s']:.1f} | "
                     f"{r['trace_cpu_s'] + r['compile_cpu_s']:.1f} | "
                     f"{r['trace_s'] + r['compile_s']:.1f} | {load} |")
    walls = [r["trace_s"] + r["compile_s"] for r in result["rows"]]
    lines += ["", f"Target: every program <= {MAX_COMPILE_S:.0f} s (trace + compile, CPU time): "
              f"{'met' if total <= MAX_COMPILE_S else 'not met'}; the longest is "
              f"{worst['experiment']} {worst['function']}, {total:.1f} CPU s; the longest "
              f"wall time is {max(walls):.1f} s. XLA's CPU compiler runs part of its work on a "
              "thread pool, so CPU time exceeds wall time on a quiet machine; on a shared "
              "machine the wall time stretches with the load, and the CPU time too, less "
              "(contention for caches and memory): compare rows of one run.", ""]
    return "\n".join(lines)


def main(argv=None):
    registry.discover()
    names = [n for n, e in registry.all_experiments().items() if e.paper_result]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiments", nargs="*", default=names,
                    choices=list(registry.all_experiments()))
    ap.add_argument("--devices", type=int, default=DEVICES,
                    help="JAX host devices (default: every usable core)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "compile_time"))
    ap.add_argument("--merge", action="store_true",
                    help="keep the other experiments' rows of the existing JSON at --out")
    args = ap.parse_args(argv)
    out = pathlib.Path(args.out)
    result = dict(benchmark="compile_time", hardware=hardware_info(), rows=[],
                  target_s=MAX_COMPILE_S)
    fresh = {name: time_experiment(name) for name in args.experiments}
    old = (json.loads(out.with_suffix(".json").read_text())["rows"]
           if args.merge and out.with_suffix(".json").exists() else [])
    kept = [r for r in old if r["experiment"] not in fresh]
    result["merged"] = bool(kept)
    by_name = {}
    for r in kept + [r for rows in fresh.values() for r in rows]:
        by_name.setdefault(r["experiment"], []).append(r)
    result["rows"] = [r for name in sorted(by_name) for r in by_name[name]]
    result["load_end"] = os.getloadavg()[0]
    cmd = "python benchmarks/compile_time.py" + (
        " --experiments " + " ".join(args.experiments) if args.experiments != names else "") + (
        " --merge" if args.merge else "")
    text = markdown(result, cmd)
    write_results(out, result, text)
    print(text)


if __name__ == "__main__":
    main()
