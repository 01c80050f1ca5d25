"""Shooting-env throughput: env steps/s vs batch size, against the NumPy reference.

Each batch size runs ``T`` steps of ``vmap(ShootingEnv.step)`` (auto-reset, random
actions drawn inside a ``lax.scan``), compiled and warmed up first, timed with
``block_until_ready`` (best of ``--reps``). The baseline, in the same process, is the
plain NumPy reference (``tests/reference/world_np.py`` + ``tests/reference/camera_np.py``)
run episode by episode with random actions; the world-only reference is reported too,
because the camera reference samples ball outlines numerically and is slow.

Usage::

    python benchmarks/env_throughput.py            # batches 1..65536, ~10 min on 2 cores
    python benchmarks/env_throughput.py --quick    # about a minute
Writes benchmarks/results/env_throughput.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import vbl  # noqa: E402,F401
from tests.reference import world_np  # noqa: E402
from tests.reference.camera_np import section2_features_np  # noqa: E402
from vbl.envs.shooting import ShootingEnv  # noqa: E402


def cpu_model() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def make_runner(env, params, batch: int, steps: int):
    n_act = env.num_actions

    @jax.jit
    def run(key):
        k0, k1 = jax.random.split(key)
        _, state = jax.vmap(env.reset, (0, None))(jax.random.split(k0, batch), params)

        def body(carry, _):
            state, key = carry
            key, k_act, k_step = jax.random.split(key, 3)
            actions = jax.random.randint(k_act, (batch,), 0, n_act, jnp.int32)
            _, state, reward, _, _, info = jax.vmap(env.step, (0, 0, 0, None))(
                jax.random.split(k_step, batch), state, actions, params)
            return (state, key), (reward.sum(), info["episode_done"].sum())

        (state, _), (rew, done) = jax.lax.scan(body, (state, k1), None, length=steps)
        return rew.sum(), done.sum()

    return run


def time_jax(env, params, batch, steps, reps):
    run = make_runner(env, params, batch, steps)
    t0 = time.perf_counter()
    jax.block_until_ready(run(jax.random.key(0)))  # compile + warm-up
    compile_s = time.perf_counter() - t0
    best = np.inf
    for r in range(reps):
        t0 = time.perf_counter()
        rew, done = jax.block_until_ready(run(jax.random.key(r + 1)))
        best = min(best, time.perf_counter() - t0)
    # the timed run includes the batched reset before the scan (one extra step's worth)
    return dict(batch=batch, steps=steps, seconds=best, steps_per_s=batch * steps / best,
                compile_s=compile_s, goals=float(rew), episodes_done=int(done))


def time_numpy(env, params, seconds, with_camera):
    """Reference episodes one by one, random actions, until `seconds` have passed."""
    rng = np.random.default_rng(0)
    wp = params.world
    corners = world_np.goal_corners_np(wp)
    starts = jax.vmap(env.sample_start, (0, None))(jax.random.split(jax.random.key(0), 256),
                                                   params)
    starts = jax.tree_util.tree_map(np.asarray, starts)
    n_steps = n_ep = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        i = n_ep % 256
        s = dict(robots=starts.robots[i].tolist(), ball=starts.ball[i].tolist(),
                 vel=[0.0, 0.0], scored=False, out=False)
        for t in range(params.max_steps):
            s, ev = world_np.step_world(s, [int(rng.integers(0, env.num_actions))], wp)
            if with_camera:
                section2_features_np(np.array(s["robots"][0]), np.array(s["ball"]),
                                     wp.ball.radius, corners, params.camera)
            n_steps += 1
            if ev["goal"] or ev["ball_out"] or t + 1 >= params.max_steps:
                break
            if time.perf_counter() - t0 > seconds:
                break
        n_ep += 1
    dt = time.perf_counter() - t0
    return dict(steps=n_steps, seconds=dt, steps_per_s=n_steps / dt)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, about a minute")
    ap.add_argument("--batches", type=int, nargs="*", default=None)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "env_throughput"))
    args = ap.parse_args(argv)
    batches = args.batches or ([1, 64, 4096] if args.quick else
                               [1, 4, 16, 64, 256, 1024, 4096, 16384, 65536])
    target_steps = 2**18 if args.quick else 2**21
    env = ShootingEnv()
    params = env.default_params
    rows = []
    for b in batches:
        steps = int(min(max(target_steps // b, 20), 2000 if args.quick else 5000))
        row = time_jax(env, params, b, steps, args.reps)
        rows.append(row)
        print(f"batch {b:6d}: {row['steps_per_s'] / 1e6:8.3f} M steps/s "
              f"(T={steps}, compile {row['compile_s']:.1f} s)", flush=True)
    ref_s = 5.0 if args.quick else 20.0
    ref_full = time_numpy(env, params, ref_s, with_camera=True)
    ref_world = time_numpy(env, params, ref_s / 2, with_camera=False)
    print(f"NumPy reference world+camera: {ref_full['steps_per_s']:.1f} steps/s; "
          f"world only: {ref_world['steps_per_s']:.1f} steps/s")
    for r in rows:
        r["speedup_vs_numpy"] = r["steps_per_s"] / ref_full["steps_per_s"]
        r["speedup_vs_numpy_world_only"] = r["steps_per_s"] / ref_world["steps_per_s"]
    hw = dict(cpu=cpu_model(), cores=os.cpu_count(), jax=jax.__version__,
              devices=[str(d) for d in jax.devices()], python=platform.python_version(),
              load_avg=os.getloadavg())
    result = dict(benchmark="env_throughput", env="ShootingEnv(two_motor)",
                  substeps=params.world.substeps, quick=args.quick, hardware=hw, jax=rows,
                  numpy_reference=ref_full, numpy_reference_world_only=ref_world,
                  targets=dict(steps_per_s_at_4096=5e6, speedup=300))
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=2))
    lines = [f"Shooting env throughput ({hw['cpu']}, {hw['cores']} cores, jax {hw['jax']}, "
             f"load average {hw['load_avg'][0]:.1f} at the end; `python "
             f"benchmarks/env_throughput.py{' --quick' if args.quick else ''}`)", "",
             "| batch | env steps/s | x NumPy ref (world+camera) | x NumPy ref (world only) |",
             "|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['batch']:,} | {r['steps_per_s']:,.0f} | "
                     f"{r['speedup_vs_numpy']:,.0f} | {r['speedup_vs_numpy_world_only']:,.0f} |")
    lines += ["", f"NumPy reference, episode by episode: {ref_full['steps_per_s']:,.1f} steps/s "
              f"(world + camera), {ref_world['steps_per_s']:,.0f} steps/s (world only).", ""]
    out.with_suffix(".md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
