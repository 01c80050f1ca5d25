"""Sweep scaling: the real learners' training step on 1 vs 2 devices and 1 vs 2 processes,
16 to 4,096 learners, with a scaling model that predicts Table 2's wall time on H hosts x D
devices.

Learners: Table 2's (``table2_shoot_pass``, the first compile group of its default sweep:
``ball_velocity=False``, 4 points) and the grid baseline's (``grid_shooting``, 2 points).
A row of N learners takes the group's first N learners (seeds = N / points, rounded up),
beyond :data:`DISTINCT_LEARNERS` repeating their carries (init is not timed).
Each configuration runs in its own subprocess: 1 process with 1 forced CPU device, 1
process with 2 (``--xla_force_host_platform_device_count``), and 2 processes of 1 device
each joined by ``jax.distributed`` on 127.0.0.1. The step is compiled as the engine
compiles it (``jit(shard_map(vmap(step)))`` over every device), run once as a warm-up
chunk, then timed over ``--chunks`` chunks, best of ``--reps``; every chunk's metrics are
gathered to the host (``to_host``, as the engine gathers them) and folded into the result,
and the carry is awaited (``block_until_ready``). Wall and CPU time (all processes' CPU),
load average at the start and end of each row.

Scaling: strong (same learners: speedup = t(1 device) / t(2), efficiency = speedup / 2) and
weak (learners per device fixed: efficiency = t(1 device, N/2) / t(2, N); the 1-device run
also times N/2 learners). The model (:func:`fit`, :func:`chunk_seconds`,
:func:`run_seconds`; docs/engine.md, "Scaling model") is fitted on the 1-device rows and
predicts every row, then Table 2 with ``SEEDS`` seeds.

    python benchmarks/sweep_scaling.py [--quick] [--out DIR]
    python benchmarks/sweep_scaling.py --rebuild [--out DIR]   # model and tables only
Writes DIR/sweep_scaling.{json,md} (default benchmarks/results); while it runs,
DIR/sweep_scaling.partial.json holds the rows of the configurations done so far.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # for benchmarks.hardware and vbl

EXPERIMENTS = ("table2_shoot_pass", "grid_shooting")
PREDICTED = "table2_shoot_pass"  #: the experiment whose full run the model predicts
SIZES = (16, 64, 256, 1024, 4096)  #: learners of the 2-device / 2-process rows
QUICK_SIZES = (16,)
QUICK_EXPERIMENTS = (PREDICTED,)  #: --quick: Table 2's learners only
TINY_SIZES = (2,)
CONFIGS = ((1, 1), (1, 2), (2, 1))  #: (processes, devices per process)
TINY_SETS = {  # a few steps of a few envs: the test's size, not a measurement
    "table2_shoot_pass": ["agent.chunk_steps=10", "agent.num_envs=2", "env.max_steps=10"],
    "grid_shooting": ["agent.chunk_steps=10", "agent.num_envs=2", "train.eval_every=1",
                      "train.eval_chunks=1", "env.max_steps=10"],
}
WORKER_TIMEOUT_S = 4 * 3600
DISTINCT_LEARNERS = 64
"""A row of more learners repeats the init of its first this many (learner i runs learner
i mod 64's carry and config): init is not timed, and Table 2's costs about 0.2 s and 23 MB
per learner; every learner still runs its own step."""

SEEDS = 1024  #: seeds of the predicted Table 2 run
GRID = (1, 2, 4, 8)  #: hosts H and devices per host D of the prediction
GPU_FACTOR = 20.0
"""Assumption, not a measurement: one GPU computes a learner-chunk this many times faster
than one CPU device measured here; its fixed cost per chunk and compile time are the CPU's."""
HOST_LINK_BYTES_PER_S = 1e9
"""Assumption: bytes/s each host sends to the others when metrics and checkpointed carries
are gathered (``process_allgather``; about a 10 Gbit/s link)."""
DISK_BYTES_PER_S = 2e8
"""Assumption: bytes/s process 0 writes checkpoints at."""


# ---------------------------------------------------------------- the scaling model


@dataclass(frozen=True)
class Model:
    """Seconds per chunk = ``learner_chunk_s`` x learners per device + ``chunk_s`` +
    transfers (:func:`chunk_seconds`). Bytes per learner: ``metric_bytes`` gathered every
    chunk, ``carry_bytes`` gathered and written every ``checkpoint_every`` chunks."""

    learner_chunk_s: float
    chunk_s: float
    compile_s: float = 0.0
    metric_bytes: float = 0.0
    carry_bytes: float = 0.0
    checkpoint_every: int = 10


def fit(rows: list[dict]) -> Model:
    """Least squares of seconds per chunk on learners per device over ``rows`` (one
    experiment's 1-process 1-device rows), both coefficients kept >= 0; bytes per learner
    and compile time from the largest row."""
    per_dev = np.array([r["learners_per_device"] for r in rows], float)
    t = np.array([r["s_per_chunk"] for r in rows], float)
    if len(set(per_dev)) > 1:
        a, b = np.linalg.lstsq(np.stack([per_dev, np.ones_like(per_dev)], 1), t, rcond=None)[0]
    else:
        a, b = 0.0, -1.0
    if b < 0 or a < 0:  # noise or one size: through the origin
        a, b = float(np.sum(per_dev * t) / np.sum(per_dev ** 2)), 0.0
    big = max(rows, key=lambda r: r["learners"])
    return Model(learner_chunk_s=float(a), chunk_s=float(b), compile_s=big["compile_s"],
                 metric_bytes=big["metric_bytes"] / big["padded"],
                 carry_bytes=big["carry_bytes"] / big["padded"],
                 checkpoint_every=big["checkpoint_every"])


def transfer_seconds(m: Model, learners: int, hosts: int, checkpoints: bool = True) -> float:
    """Per chunk: the gather of metrics and (with ``checkpoints``: every
    ``checkpoint_every`` chunks) carries from the other hosts over
    ``HOST_LINK_BYTES_PER_S``, and the checkpoint's write at ``DISK_BYTES_PER_S``."""
    ckpt = m.carry_bytes * learners / m.checkpoint_every if checkpoints else 0.0
    remote = (m.metric_bytes * learners + ckpt) * (hosts - 1) / hosts
    return remote / HOST_LINK_BYTES_PER_S + ckpt / DISK_BYTES_PER_S


def chunk_seconds(m: Model, learners: int, hosts: int, devices: int, speed: float = 1.0,
                  checkpoints: bool = True) -> float:
    """Predicted wall seconds of one chunk of ``learners`` on ``hosts`` x ``devices``
    (devices per host); ``speed``: a device's compute against the one measured;
    ``checkpoints``: count the checkpoints' share (a run does, the benchmark's rows not)."""
    per_dev = math.ceil(learners / (hosts * devices))
    return (m.learner_chunk_s * per_dev / speed + m.chunk_s
            + transfer_seconds(m, learners, hosts, checkpoints))


def run_seconds(m: Model, hosts: int, devices: int, seeds: int, points: int, groups: int,
                chunks: int, learner_batch: int = 4096, speed: float = 1.0) -> float:
    """Predicted wall seconds of a run: ``groups`` groups of ``points`` x ``seeds`` learners,
    ``chunks`` chunks each, in compiled calls of at most ``learner_batch`` learners (the
    engine's batches), one compilation per group."""
    n, size = _layout(seeds * points, hosts * devices, learner_batch)
    per_chunk = n * chunk_seconds(m, size, hosts, devices, speed)
    return groups * (chunks * per_chunk + m.compile_s)


def _layout(learners: int, devices: int, learner_batch: int) -> tuple[int, int]:
    """(batches, batch size), as ``vbl.engine.sharding.batch_layout``."""
    cap = max(devices, (learner_batch // devices) * devices)
    nb = math.ceil(learners / cap)
    return nb, math.ceil(math.ceil(learners / nb) / devices) * devices


# ---------------------------------------------------------------- the worker (one configuration)


def _fold(acc: dict, metrics: dict) -> dict:
    out = dict(acc)
    for k, v in metrics.items():
        out[k] = out.get(k, 0.0) + float(np.sum(np.asarray(v, np.float64)))
    return out


def _nbytes(tree) -> int:
    import jax

    return int(sum(np.dtype(x.dtype).itemsize * math.prod(x.shape)
                   for x in jax.tree.leaves(tree)))


def _learner_set(exp, sets: list[str], n: int):
    """The first ``n`` learners of the experiment's first compile group: (group, keys,
    configs, plan shape)."""
    import jax

    from vbl.engine.config import parse_assignment
    from vbl.engine.runner import resolve
    from vbl.engine.sweep import make_plan

    overrides = dict(parse_assignment(s, exp.default_config) for s in sets)
    config, sweep, _, _ = resolve(exp, sets=overrides or None)
    points = len(make_plan(exp, config, sweep, 1).groups[0].point_ids)
    plan = make_plan(exp, config, sweep, -(-n // points))
    g = plan.groups[0]
    shape = dict(points=len(plan.points), groups=len(plan.groups),
                 chunks=g.num_chunks)
    return (g, g.select(plan.init_keys)[:n], jax.tree.map(lambda x: x[:n], g.configs), shape)


def time_size(exp, sets: list[str], n: int, chunks: int, reps: int) -> dict:
    """One row: ``n`` learners' compiled chunk, timed as the module says."""
    import jax

    from vbl.engine.runfolder import DEFAULT_CHECKPOINT_EVERY
    from vbl.engine.runner import _compiled
    from vbl.engine.sharding import learner_sharding, pad_index, put, to_host

    load0 = os.getloadavg()[0]
    sharding = learner_sharding()
    ndev = len(jax.devices())
    distinct = min(n, DISTINCT_LEARNERS)
    g, keys, cfgs, shape = _learner_set(exp, sets, distinct)
    init_fn, step_fn, *_ = _compiled(g.program, sharding)
    first = -(-distinct // ndev) * ndev
    pad = pad_index(distinct, first)
    carry = to_host(init_fn(put(keys[pad], sharding),
                            put(jax.tree.map(lambda x: np.asarray(x)[pad], cfgs), sharding)))
    size = -(-n // ndev) * ndev
    idx = np.arange(size) % distinct  # learner i repeats learner i mod distinct
    carry = put(jax.tree.map(lambda x: x[idx], carry), sharding)
    cfgs = put(jax.tree.map(lambda x: np.asarray(x)[idx], cfgs), sharding)
    t0 = time.perf_counter()
    compiled = step_fn.lower(carry, cfgs).compile()
    compile_s = time.perf_counter() - t0
    carry, m = compiled(carry, cfgs)  # warm-up chunk
    acc = _fold({}, to_host(m))
    metric_bytes = _nbytes(m)
    jax.block_until_ready(carry)
    best_wall, best_cpu = math.inf, math.inf
    for _ in range(reps):
        c0, t0 = time.process_time(), time.perf_counter()
        for _ in range(chunks):
            carry, m = compiled(carry, cfgs)
            acc = _fold(acc, to_host(m))
        jax.block_until_ready(carry)
        best_wall = min(best_wall, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return dict(experiment=exp.name, sets=list(sets), processes=jax.process_count(),
                devices=ndev, learners=n, padded=size, learners_per_device=size // ndev,
                chunks=chunks, reps=reps, wall_s=best_wall, cpu_s=best_cpu,
                s_per_chunk=best_wall / chunks, compile_s=compile_s,
                metric_bytes=metric_bytes, carry_bytes=_nbytes(carry),
                checkpoint_every=DEFAULT_CHECKPOINT_EVERY, plan=shape,
                metrics_sum=sum(acc.values()), load_start=load0, load_end=os.getloadavg()[0])


def worker(args) -> list[dict]:
    import vbl  # noqa: F401  (x64 on, as in every vbl process)
    from vbl.engine import distributed, registry
    from vbl.engine.jax_setup import engine_precision

    if args.coordinator:
        distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    registry.discover()
    exp = registry.get(args.experiment)
    with engine_precision():
        return [time_size(exp, args.sets, int(n), args.chunks, args.reps)
                for n in args.learners.split(",")]


# ---------------------------------------------------------------- the driver


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_config(name: str, processes: int, devices: int, sizes: list[int], sets: list[str],
               chunks: int, reps: int) -> list[dict]:
    """Rows of one configuration: its worker process(es); a 2-process row has process 0's
    wall time and both processes' CPU time."""
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}",
               TF_CPP_MIN_LOG_LEVEL="3", VBL_JAX_CACHE="0")  # time real compilations
    cmd = [sys.executable, __file__, "--worker", "--experiment", name, "--learners",
           ",".join(map(str, sizes)), "--chunks", str(chunks), "--reps", str(reps)]
    cmd += [f"--set={s}" for s in sets]
    if processes > 1:
        addr = f"127.0.0.1:{_free_port()}"
        cmds = [cmd + ["--coordinator", addr, "--num-processes", str(processes),
                       "--process-id", str(i)] for i in range(processes)]
    else:
        cmds = [cmd]
    procs = [subprocess.Popen(c, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for c in cmds]
    outs = [p.communicate(timeout=WORKER_TIMEOUT_S) for p in procs]
    for p, (_, err) in zip(procs, outs, strict=True):
        if p.returncode != 0:
            sys.exit(f"{name}: worker ({processes} process(es) x {devices} device(s)) "
                     f"failed:\n{err[-3000:]}")
    per_proc = [json.loads(out.strip().splitlines()[-1]) for out, _ in outs]
    rows = per_proc[0]
    for i, r in enumerate(rows):
        r["cpu_s"] = sum(p[i]["cpu_s"] for p in per_proc)
    return rows


def add_scaling(rows: list[dict]) -> None:
    """Strong and weak efficiency of every multi-device row against the 1-device rows."""
    one = {(r["experiment"], r["learners"]): r["s_per_chunk"] for r in rows
           if r["devices"] == 1}
    for r in rows:
        if r["devices"] == 1:
            continue
        t1 = one.get((r["experiment"], r["learners"]))
        half = one.get((r["experiment"], r["learners"] // r["devices"]))
        if t1:
            r["speedup"] = t1 / r["s_per_chunk"]
            r["strong_efficiency"] = r["speedup"] / r["devices"]
        if half:
            r["weak_efficiency"] = half / r["s_per_chunk"]


def add_model(rows: list[dict], speed: float) -> dict:
    """Fit the model per experiment; each row's prediction; Table 2's predicted run."""
    out = {}
    for name in dict.fromkeys(r["experiment"] for r in rows):
        mine = [r for r in rows if r["experiment"] == name]
        model = fit([r for r in mine if r["devices"] == 1])
        for r in mine:
            r["predicted_s_per_chunk"] = chunk_seconds(
                model, r["padded"], r["processes"], r["devices"] // r["processes"],
                checkpoints=False)
        out[name] = dict(model=asdict(model), check=model_check(mine))
        if name == PREDICTED:
            shape = mine[0]["plan"]
            points = shape["points"] // shape["groups"]
            out[name]["run"] = dict(seeds=SEEDS, points_per_group=points,
                                    groups=shape["groups"], chunks=shape["chunks"],
                                    gpu_factor=speed)
            for label, s in (("cpu_hours", 1.0), ("gpu_hours", speed)):
                out[name][label] = {f"{h}x{d}": run_seconds(
                    model, h, d, SEEDS, points, shape["groups"], shape["chunks"],
                    speed=s) / 3600 for h in GRID for d in GRID}
    return out


def model_check(rows: list[dict]) -> dict:
    """Per configuration ("P x D": processes x devices per process), the median and worst
    of predicted / measured - 1 over its rows (the 1 x 1 rows are the fit's own)."""
    out = {}
    for r in rows:
        key = f"{r['processes']} x {r['devices'] // r['processes']}"
        out.setdefault(key, []).append(r["predicted_s_per_chunk"] / r["s_per_chunk"] - 1)
    return {k: dict(median=float(np.median(v)), worst=float(max(v, key=abs)), rows=len(v))
            for k, v in out.items()}


def markdown(result: dict) -> str:
    hw, rows = result["hardware"], result["rows"]
    lines = [f"Sweep scaling: the real learners' compiled training chunk, {result['chunks']} "
             f"timed chunk(s) after a warm-up chunk, best of {result['reps']}, metrics "
             f"gathered and folded every chunk. {hw['cpu']}, {hw['cores']} cores, jax "
             f"{hw['jax']}; load average {result['load_start']:.1f} at the start and "
             f"{result['load_end']:.1f} at the end. `{result['command']}`", ""]
    if result["tiny"]:
        lines += ["**Tiny run** (a few steps of a few envs): a test of the script, not a "
                  "measurement; its predictions say nothing about the real run.", ""]
    lines += ["Strong scaling: same learners, speedup = t(1 device) / t, efficiency = "
              "speedup / 2. Weak scaling: same learners per device, efficiency = t(1 device, "
              "N/2 learners) / t(2, N). Predicted: the scaling model fitted on the 1-device "
              "rows (docs/engine.md, \"Scaling model\").", "",
              "| experiment | processes x devices | learners | s / chunk | predicted s | CPU "
              "s / chunk | strong speedup | strong eff. | weak eff. | compile s | load |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]

    def opt(r, k, f):
        return format(r[k], f) if k in r else "-"

    for r in rows:
        lines.append(
            f"| {r['experiment']} | {r['processes']} x {r['devices'] // r['processes']} | "
            f"{r['learners']:,} | {r['s_per_chunk']:.4g} | {r['predicted_s_per_chunk']:.4g} | "
            f"{r['cpu_s'] / r['chunks']:.4g} | {opt(r, 'speedup', '.2f')} | "
            f"{opt(r, 'strong_efficiency', '.2f')} | {opt(r, 'weak_efficiency', '.2f')} | "
            f"{r['compile_s']:.0f} | {r['load_start']:.1f}-{r['load_end']:.1f} |")
    for name, fitted in result["model"].items():
        m = fitted["model"]
        lines += ["", f"Model of {name}: {m['learner_chunk_s'] * 1e3:.4g} ms per learner-chunk "
                  f"per device + {m['chunk_s'] * 1e3:.4g} ms per chunk; per learner "
                  f"{m['metric_bytes']:,.0f} bytes of metrics gathered every chunk and "
                  f"{m['carry_bytes']:,.0f} bytes of carry gathered and checkpointed every "
                  f"{m['checkpoint_every']} chunks; compile {m['compile_s']:.0f} s."]
        if "check" in fitted:
            lines += ["", "Model check, predicted / measured - 1 (median, worst) per "
                      "configuration: " + "; ".join(
                          f"{k}{' (fitted)' if k == '1 x 1' else ''}: {c['median']:+.0%}, "
                          f"{c['worst']:+.0%} over {c['rows']} rows"
                          for k, c in fitted["check"].items()) + "."]
        if "run" in fitted:
            run = fitted["run"]
            lines += ["", f"Predicted wall time of {name} with {run['seeds']:,} seeds "
                      f"({run['groups']} groups x {run['points_per_group']} points x "
                      f"{run['seeds']:,} seeds, {run['chunks']} chunks per group), hours, "
                      f"CPU devices as measured here:", ""]
            lines += _grid_table(fitted["cpu_hours"])
            lines += ["", f"GPU, a prediction, not a measurement: assumes one GPU computes a "
                      f"learner-chunk {run['gpu_factor']:g}x faster than one CPU device "
                      f"here, with the CPU's fixed cost per chunk and compile time:", ""]
            lines += _grid_table(fitted["gpu_hours"])
    return "\n".join(lines) + "\n"


def _grid_table(hours: dict) -> list[str]:
    lines = ["| hosts \\ devices per host | " + " | ".join(map(str, GRID)) + " |",
             "|---|" + "---:|" * len(GRID)]
    for h in GRID:
        lines.append(f"| {h} | " + " | ".join(f"{hours[f'{h}x{d}']:.3g}" for d in GRID) + " |")
    return lines


def measure(names: list[str], sizes: tuple[int, ...], tiny: bool, chunks: int,
            reps: int, partial: Path | None = None) -> list[dict]:
    """Every configuration's rows; after each, the rows so far are written to ``partial``
    (a stopped run keeps what it measured)."""
    rows = []
    one = sorted(set(sizes) | {n // 2 for n in sizes if n >= 2})
    for name in names:
        sets = TINY_SETS[name] if tiny else []
        for procs, devs in CONFIGS:
            rows += run_config(name, procs, devs, one if procs * devs == 1 else list(sizes),
                               sets, chunks, reps)
            print(f"{name}: {procs} process(es) x {devs} device(s) done", file=sys.stderr,
                  flush=True)
            if partial is not None:
                partial.parent.mkdir(parents=True, exist_ok=True)
                partial.write_text(json.dumps(rows, indent=1))
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="16 learners, Table 2's only unless --experiments says otherwise")
    ap.add_argument("--experiments", nargs="+", choices=EXPERIMENTS,
                    help="learners to time (default: both)")
    ap.add_argument("--chunks", type=int, default=1, help="chunks timed per repetition")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--gpu-factor", type=float, default=GPU_FACTOR,
                    help="assumed GPU compute per learner-chunk vs one CPU device here")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"),
                    help="folder of sweep_scaling.{json,md}")
    ap.add_argument("--tiny", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--experiment", help=argparse.SUPPRESS)
    ap.add_argument("--learners", help=argparse.SUPPRESS)
    ap.add_argument("--set", dest="sets", action="append", default=[], help=argparse.SUPPRESS)
    ap.add_argument("--coordinator", help=argparse.SUPPRESS)
    ap.add_argument("--num-processes", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--process-id", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--rebuild", action="store_true",
                    help="rewrite OUT/sweep_scaling.{json,md} from the rows of its JSON "
                         "(the model and the tables of today's script; nothing is timed)")
    args = ap.parse_args(argv)
    if args.rebuild:
        from benchmarks.hardware import write_results

        path = Path(args.out) / "sweep_scaling"
        result = json.loads(path.with_suffix(".json").read_text())
        result["model"] = add_model(result["rows"], result["assumptions"]["gpu_factor"])
        write_results(path, result, markdown(result))
        return
    if args.worker:
        print(json.dumps(worker(args)))
        return
    if args.chunks < 1 or args.reps < 1 or not args.gpu_factor > 0:
        ap.error("--chunks and --reps must be >= 1 and --gpu-factor > 0")
    from benchmarks.hardware import hardware_info, write_results

    sizes = TINY_SIZES if args.tiny else QUICK_SIZES if args.quick else SIZES
    args.experiments = args.experiments or list(QUICK_EXPERIMENTS if args.quick else EXPERIMENTS)
    load0 = os.getloadavg()[0]
    partial = Path(args.out) / "sweep_scaling.partial.json"
    rows = measure(args.experiments, sizes, args.tiny, args.chunks, args.reps, partial)
    add_scaling(rows)
    command = " ".join(["python benchmarks/sweep_scaling.py"] + ["--quick"] * args.quick
                       + ["--tiny"] * args.tiny + [f"--chunks {args.chunks}",
                                                    f"--reps {args.reps}", "--experiments",
                                                    *args.experiments])
    result = dict(benchmark="sweep_scaling", quick=args.quick, tiny=args.tiny,
                  hardware=hardware_info(), command=command, chunks=args.chunks,
                  reps=args.reps, load_start=load0, load_end=os.getloadavg()[0], rows=rows,
                  model=add_model(rows, args.gpu_factor),
                  assumptions=dict(gpu_factor=args.gpu_factor,
                                   host_link_bytes_per_s=HOST_LINK_BYTES_PER_S,
                                   disk_bytes_per_s=DISK_BYTES_PER_S))
    text = markdown(result)
    write_results(Path(args.out) / "sweep_scaling", result, text)
    partial.unlink(missing_ok=True)
    print(text)


if __name__ == "__main__":
    main()
