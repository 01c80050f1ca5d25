"""Sweep scaling: wall time and learners/s of the engine's vmapped, sharded chunk loop for
1 to 4,096 learners on 1, 2 and 4 (forced) CPU devices.

Each device count runs in its own subprocess (``XLA_FLAGS=--xla_force_host_platform_device_
count=D`` must be set before jax starts). The program is the toy bandit experiment
(10 arms, ``PULLS`` pulls per chunk); we time ``CHUNKS`` compiled chunks after a warm-up
chunk, best of ``REPEATS``. Ratios: throughput per learner against 1 learner (vectorisation
gain) and against 1 device at the same size (sharding gain; 2 physical cores here, so
more than 2 forced devices cannot add compute).

    python benchmarks/sweep_scaling.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:
    sys.path.insert(0, str(HERE.parent))  # for benchmarks.hardware
SIZES = (1, 4, 16, 64, 256, 1024, 4096)
QUICK_SIZES = (1, 64, 4096)
DEVICES = (1, 2, 4)
PULLS = 50  # arm pulls per chunk
CHUNKS = 10  # timed chunks
QUICK_CHUNKS = 3
REPEATS = 2


def worker(sizes: list[int], chunks: int) -> list[dict]:
    import jax

    import vbl  # noqa: F401  (x64 on, as in every vbl process)
    from vbl.engine.registry import get
    from vbl.engine.runner import _compiled
    from vbl.engine.sharding import batch_layout, learner_sharding, pad_index, put
    from vbl.engine.sweep import make_plan

    os.environ.setdefault("VBL_EXPERIMENTS_DIR", str(HERE.parent / "experiments"))
    exp = get("toy_bandit")
    cfg = exp.default_config.replace(train=exp.default_config.train.replace(
        pulls_per_chunk=PULLS))
    sharding = learner_sharding()
    ndev = len(jax.devices())
    out = []
    for n in sizes:
        plan = make_plan(exp, cfg, {}, seeds=n)
        g = plan.groups[0]
        init_fn, step_fn, _ = _compiled(g.program, sharding)
        nb, size = batch_layout(n, ndev, 4096)
        assert nb == 1
        idx = pad_index(n, size)
        keys = put(plan.init_keys[idx], sharding)
        cfgs = put(jax.tree.map(lambda x, i=idx: x[i], g.configs), sharding)
        t0 = time.perf_counter()
        carry, _ = step_fn(init_fn(keys, cfgs), cfgs)
        jax.block_until_ready(carry)
        compile_s = time.perf_counter() - t0
        best = float("inf")
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            for _ in range(chunks):
                carry, m = step_fn(carry, cfgs)
            jax.block_until_ready((carry, m))
            best = min(best, time.perf_counter() - t0)
        out.append({"devices": ndev, "learners": n, "padded": size, "chunks": chunks,
                    "seconds": best, "learner_chunks_per_s": n * chunks / best,
                    "pulls_per_s": n * chunks * PULLS / best, "compile_s": compile_s})
    return out


def hardware() -> dict:
    import jax

    from benchmarks.hardware import cpu_model

    return {"cpu": cpu_model(), "cores": os.cpu_count(), "jax": jax.__version__,
            "python": platform.python_version(),
            "load_avg_1min": round(os.getloadavg()[0], 2)}  # other jobs share the machine


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 sizes, 3 chunks (about a minute)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--sizes", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--chunks", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker([int(s) for s in args.sizes.split(",")], args.chunks)))
        return
    sizes = QUICK_SIZES if args.quick else SIZES
    chunks = QUICK_CHUNKS if args.quick else CHUNKS
    rows = []
    for d in DEVICES:
        env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={d}",
                   TF_CPP_MIN_LOG_LEVEL="3")
        r = subprocess.run([sys.executable, __file__, "--worker", "--sizes",
                            ",".join(map(str, sizes)), "--chunks", str(chunks)],
                           env=env, capture_output=True, text=True, timeout=3600)
        if r.returncode != 0:
            sys.exit(f"worker with {d} devices failed:\n{r.stderr[-3000:]}")
        rows += json.loads(r.stdout.strip().splitlines()[-1])
        print(f"{d} device(s) done", file=sys.stderr)
    base1 = {r["learners"]: r for r in rows if r["devices"] == 1}
    one = base1[1]["learner_chunks_per_s"]
    for r in rows:
        r["vs_1_learner"] = r["learner_chunks_per_s"] / one
        r["vs_1_device"] = r["learner_chunks_per_s"] / base1[r["learners"]]["learner_chunks_per_s"]
    hw = hardware()
    result = {"benchmark": "sweep_scaling", "quick": args.quick, "hardware": hw,
              "program": f"toy_bandit, 10 arms, {PULLS} pulls per chunk", "rows": rows}
    res_dir = HERE / "results"
    res_dir.mkdir(exist_ok=True)
    (res_dir / "sweep_scaling.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [f"Sweep scaling: toy bandit program ({PULLS} pulls per chunk), {chunks} compiled "
             f"chunks after warm-up, best of {REPEATS}. {hw['cpu']}, {hw['cores']} cores, "
             f"jax {hw['jax']}, load average {hw['load_avg_1min']} (shared machine: absolute "
             f"numbers are noisy). Ratios: learner-chunks/s against 1 learner on 1 device, and "
             f"against 1 device at the same size.", "",
             "| devices | learners | wall time (s) | learners x chunks / s | pulls / s | "
             "vs 1 learner | vs 1 device |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['devices']} | {r['learners']:,} | {r['seconds']:.4f} | "
                     f"{r['learner_chunks_per_s']:,.0f} | {r['pulls_per_s']:,.0f} | "
                     f"{r['vs_1_learner']:.1f}x | {r['vs_1_device']:.2f}x |")
    (res_dir / "sweep_scaling.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
