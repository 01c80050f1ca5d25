"""Learner throughput: each paper experiment's training step against its raw env step.

For each experiment, the engine's own plan at full scale (default config, default sweep and
seeds: the learners one ``vbl run`` compiles together) gives the program; its ``step`` is
compiled the way the engine compiles it (``jit(vmap(step))`` with the learner axis sharded
over the devices), warmed up, and timed over ``--chunks`` chunks with
``block_until_ready`` (each chunk's carry feeds the next; every metric is summed into the
result). Beside it, in the same run, the raw env of the same experiment steps the same
number of envs (learners x envs per learner) with random actions, **observation consumed**
(``benchmarks/env_throughput.py``), for the same number of primitives, split over the same
devices (the same batch per device: on one device XLA's CPU runtime spreads a step over the
cores' threads and spends more CPU time per env step than one device per core).

Primitives are *useful* primitives: env steps that advance an episode the learner trains
on. ``overhead`` = learner CPU time per primitive / raw env CPU time per primitive (target
<= 1.5). ``compile s`` is the step's trace + compile time (persistent cache off).

Usage::

    python benchmarks/learner_throughput.py            # every experiment below
    python benchmarks/learner_throughput.py --experiments table2_shoot_pass --chunks 3
    python benchmarks/learner_throughput.py --experiments grid_shooting \
        --set train.eval_curve=false --out /path/elsewhere   # what one setting costs
Writes benchmarks/results/learner_throughput.{json,md} (``--out`` elsewhere).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.devices import force_host_devices  # noqa: E402

DEVICES = force_host_devices()  # before jax is imported: --devices N, else every core
os.environ.setdefault("VBL_JAX_CACHE", "0")  # time real compilations

import jax  # noqa: E402

import vbl  # noqa: E402,F401
from benchmarks.env_throughput import time_jax  # noqa: E402
from benchmarks.hardware import hardware_info, write_results  # noqa: E402
from vbl.engine import registry  # noqa: E402
from vbl.engine.config import parse_assignment  # noqa: E402
from vbl.engine.jax_setup import engine_precision  # noqa: E402
from vbl.engine.runner import _compiled, resolve  # noqa: E402
from vbl.engine.sharding import learner_sharding, put  # noqa: E402
from vbl.engine.sweep import make_plan  # noqa: E402
from vbl.envs.shoot_pass import ShootPassEnv  # noqa: E402
from vbl.envs.shooting import ShootingEnv  # noqa: E402
from vbl.params import ParamError  # noqa: E402

MAX_OVERHEAD = 1.5  #: target: training step at most this x the raw env step (same batch)


@dataclass(frozen=True)
class Spec:
    """How to read one experiment: its raw env, envs per learner and useful primitives."""

    env: Callable[[Any], tuple[Any, Any]]       # config -> (env, env params)
    envs_per_learner: Callable[[Any], int]      # config -> envs one learner steps
    primitives: Callable[[Any, dict], float]    # (config, summed metrics) -> primitives


SPECS = {
    # async macro actions: every runner step is one primitive of every env
    "table2_shoot_pass": Spec(
        env=lambda c: (ShootPassEnv("shoot"), c.env),
        envs_per_learner=lambda c: c.agent.num_envs,
        primitives=lambda c, m: c.agent.chunk_steps * c.agent.num_envs * m["learners"]),
    # async macro actions as well; one engine chunk trains train.eval_every chunks
    "grid_shooting": Spec(
        env=lambda c: (ShootingEnv(), c.env),
        envs_per_learner=lambda c: c.agent.num_envs,
        primitives=lambda c, m: (c.train.eval_every * c.agent.chunk_steps * c.agent.num_envs
                                 * m["learners"])),
}


def _sum_metrics(acc, metrics):
    out = dict(acc)
    for k, v in metrics.items():
        out[k] = out.get(k, 0.0) + float(np.sum(np.asarray(v, np.float64)))
    return out


def time_experiment(name: str, chunks: int, reps: int, sets: list[str] = ()) -> dict:
    """One row: the experiment's step as the engine compiles and runs it (inside
    :func:`vbl.engine.jax_setup.engine_precision`) beside its raw env; ``sets``: overrides
    ``PATH=VALUE`` as ``vbl run --set`` takes them."""
    with engine_precision():
        return _time_experiment(name, chunks, reps, sets)


def _time_experiment(name: str, chunks: int, reps: int, sets: list[str]) -> dict:
    exp = registry.get(name)
    spec = SPECS[name]
    overrides = dict(parse_assignment(s, exp.default_config) for s in sets)
    config, sweep, seeds, _ = resolve(exp, sets=overrides or None)
    plan = make_plan(exp, config, sweep, seeds)
    group = plan.groups[0]
    prog, n = group.program, group.num_learners
    sharding = learner_sharding()
    init_fn, step_fn, *_ = _compiled(prog, sharding)
    keys = put(np.tile(plan.init_keys, (len(group.point_ids), 1)), sharding)
    cfgs = put(group.configs, sharding)
    carry = jax.block_until_ready(init_fn(keys, cfgs))
    t0 = time.perf_counter()
    compiled = step_fn.lower(carry, cfgs).compile()
    compile_s = time.perf_counter() - t0
    carry, m = jax.block_until_ready(compiled(carry, cfgs))  # warm-up chunk
    best_cpu, best_wall, acc = np.inf, np.inf, {}
    for _ in range(reps):
        c0, t0 = time.process_time(), time.perf_counter()
        acc = {"learners": 0.0}
        for _ in range(chunks):
            carry, m = compiled(carry, cfgs)
            acc = _sum_metrics(acc, jax.block_until_ready(m))
        best_cpu = min(best_cpu, time.process_time() - c0)
        best_wall = min(best_wall, time.perf_counter() - t0)
    acc["learners"] = float(n * chunks)
    prims = float(spec.primitives(group.base_config, acc))
    env, env_params = spec.env(group.base_config)
    n_envs = n * spec.envs_per_learner(group.base_config)
    steps = max(int(round(prims / n_envs)), 20)
    n_dev = len(jax.devices())  # the learners' devices: the same per-device batch
    raw = time_jax(env, env_params, n_envs, steps, reps, n_dev if n_envs % n_dev == 0 else 1)
    learner_us = best_cpu / prims * 1e6
    return dict(experiment=name, sets=list(sets), learners=n, envs=n_envs, chunks=chunks,
                primitives=prims, learner_primitives_per_s=prims / best_wall,
                learner_cpu_us_per_primitive=learner_us, step_compile_s=compile_s,
                raw_env_steps_per_s=raw["steps_per_s"],
                raw_env_cpu_us_per_step=raw["cpu_us_per_step"],
                overhead=learner_us / raw["cpu_us_per_step"])


def markdown(result: dict, cmd: str) -> str:
    hw = result["hardware"]
    lines = [f"Learner throughput ({hw['cpu']}, {hw['cores']} cores, {len(hw['devices'])} "
             f"device(s), jax {hw['jax']}, load average {hw['load_average']:.1f} at the start "
             f"and {result['load_end']:.1f} at the end; `{cmd}`)", "",
             "| experiment | learners x envs | primitives/s | CPU us/primitive | raw env "
             "steps/s | raw env CPU us/step | overhead | step compile s |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in result["rows"]:
        lines.append(f"| {r['experiment']} | {r['learners']} x {r['envs'] // r['learners']} | "
                     f"{r['learner_primitives_per_s']:,.0f} | "
                     f"{r['learner_cpu_us_per_primitive']:.2f} | "
                     f"{r['raw_env_steps_per_s']:,.0f} | {r['raw_env_cpu_us_per_step']:.2f} | "
                     f"{r['overhead']:.2f} | {r['step_compile_s']:.0f} |")
    met = all(r["overhead"] <= MAX_OVERHEAD for r in result["rows"])
    lines += ["", f"Target: overhead (learner CPU time per useful primitive / raw env CPU time "
              f"per step with observation, same batch) <= {MAX_OVERHEAD}: "
              f"{'met' if met else 'not met'}. The machine is shared: compare columns of one "
              "row.", ""]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiments", nargs="*", default=list(SPECS), choices=list(SPECS))
    ap.add_argument("--chunks", type=int, default=3, help="chunks timed per repetition")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="one chunk, one repetition")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="PATH=VALUE",
                    help="override a parameter of every experiment timed, as `vbl run --set` "
                         "(e.g. to measure what one setting costs; give --out elsewhere)")
    ap.add_argument("--devices", type=int, default=DEVICES,
                    help="JAX host devices (default: every usable core)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                         "learner_throughput"))
    args = ap.parse_args(argv)
    chunks, reps = (1, 1) if args.quick else (args.chunks, args.reps)
    registry.discover()
    result = dict(benchmark="learner_throughput", hardware=hardware_info(), rows=[],
                  target_overhead=MAX_OVERHEAD)
    for name in args.experiments:
        try:
            row = time_experiment(name, chunks, reps, args.sets)
        except ParamError as e:  # a bad --set: one line, exit 2
            ap.error(f"{name}: {e}")
        print(json.dumps(row), flush=True)
        result["rows"].append(row)
    result["load_end"] = os.getloadavg()[0]
    out = pathlib.Path(args.out)
    cmd = "python benchmarks/learner_throughput.py" + (" --quick" if args.quick else "") + (
        f" --devices {args.devices}" if "--devices" in (argv or sys.argv) else "") + "".join(
        f" --set {s}" for s in args.sets)
    text = markdown(result, cmd)
    write_results(out, result, text)
    print(text)


if __name__ == "__main__":
    main()
