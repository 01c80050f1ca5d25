"""Shooting-env throughput: env steps/s vs batch size, against the NumPy reference.

Each batch size runs ``T`` steps of ``vmap(ShootingEnv.step)`` (auto-reset, random
actions drawn inside a ``lax.scan``), compiled and warmed up first, timed with
``block_until_ready`` (best of ``--reps``); ``--devices 2`` also runs it with the batch
split over 2 forced CPU devices (``pmap``). The baseline, in the same process, is
``benchmarks/numpy_env.py`` (closed-form NumPy world + Section 2 features, run episode by
episode with random actions; checked against the JAX env first); the test oracles
(``tests/reference``, whose camera samples the ball outline by brute force) are reported
for completeness.

Usage::

    python benchmarks/env_throughput.py --devices 2   # batches 1..65536
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

if "--devices" in sys.argv:  # forced host devices must be set before jax is imported
    _n = sys.argv[sys.argv.index("--devices") + 1]
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + f" --xla_force_host_platform_device_count={_n}")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import vbl  # noqa: E402,F401
from benchmarks import numpy_env  # noqa: E402
from benchmarks.hardware import cpu_model  # noqa: E402
from tests.reference import world_np  # noqa: E402
from tests.reference.camera_np import section2_features_np  # noqa: E402
from vbl.envs.shooting import ShootingEnv  # noqa: E402


def make_runner(env, params, batch: int, steps: int, n_dev: int = 1):
    """Jitted ``run(key)``: batched reset, then ``steps`` auto-resetting steps in a scan.

    With ``n_dev > 1`` the batch is split over the devices with ``pmap`` (batch / n_dev
    envs each); ``key`` is then a (n_dev,) key array.
    """
    n_act = env.num_actions
    local = batch // n_dev

    def run(key):
        k0, k1 = jax.random.split(key)
        _, state = jax.vmap(env.reset, (0, None))(jax.random.split(k0, local), params)

        def body(carry, _):
            state, key = carry
            key, k_act, k_step = jax.random.split(key, 3)
            actions = jax.random.randint(k_act, (local,), 0, n_act, jnp.int32)
            _, state, reward, _, _, info = jax.vmap(env.step, (0, 0, 0, None))(
                jax.random.split(k_step, local), state, actions, params)
            return (state, key), (reward.sum(), info["episode_done"].sum())

        (state, _), (rew, done) = jax.lax.scan(body, (state, k1), None, length=steps)
        return rew.sum(), done.sum()

    return jax.jit(run) if n_dev == 1 else jax.pmap(run)


def time_jax(env, params, batch, steps, reps, n_dev=1, impl="threefry2x32"):
    run = make_runner(env, params, batch, steps, n_dev)

    def key(i):
        k = jax.random.key(i, impl=impl)
        return k if n_dev == 1 else jax.random.split(k, n_dev)

    t0 = time.perf_counter()
    jax.block_until_ready(run(key(0)))  # compile + warm-up
    compile_s = time.perf_counter() - t0
    best = np.inf
    for r in range(reps):
        t0 = time.perf_counter()
        rew, done = jax.block_until_ready(run(key(r + 1)))
        best = min(best, time.perf_counter() - t0)
    # the timed run includes the batched reset before the scan (one extra step's worth)
    return dict(batch=batch, steps=steps, devices=n_dev, prng=impl, seconds=best,
                steps_per_s=batch * steps / best, compile_s=compile_s,
                goals=float(np.sum(rew)), episodes_done=int(np.sum(done)))


def draw_starts(env, params, n):
    starts = jax.vmap(env.sample_start, (0, None))(jax.random.split(jax.random.key(0), n),
                                                   params)
    starts = jax.tree_util.tree_map(np.asarray, starts)
    return [dict(robots=starts.robots[i, 0].tolist(), ball=starts.ball[i].tolist())
            for i in range(n)]


def check_numpy_env(env, params, n=64, steps=5):
    """The NumPy baseline agrees with the JAX env: n episodes x `steps` steps (world and
    features to 1e-4 of each feature's range, positions to 1e-4 m). Returns max errors."""
    tol = np.array([512, 512, 480, 512, 2, 1, 1, 1, 1]) * 1e-4
    keys = jax.random.split(jax.random.key(7), n)
    _, st = jax.vmap(env.reset, (0, None))(keys, params)
    acts = np.asarray(jax.random.randint(jax.random.key(8), (steps, n), 0, env.num_actions))
    step = jax.jit(jax.vmap(lambda s, a: env.step_env(jax.random.key(0), s, a, params)))
    wp = params.world
    corners = world_np.goal_corners_np(wp).tolist()
    s_np = [dict(robots=np.asarray(st.world.robots[i]).tolist(),
                 ball=np.asarray(st.world.ball[i]).tolist(), vel=[0.0, 0.0], scored=False,
                 out=False) for i in range(n)]
    err_obs = err_pos = 0.0
    for t in range(steps):
        obs, st, *_ = step(st, jnp.asarray(acts[t], jnp.int32))
        obs, rob, ball = map(np.asarray, (obs, st.world.robots, st.world.ball))
        for i in range(n):
            s_np[i], _ = world_np.step_world(s_np[i], [int(acts[t, i])], wp)
            o = numpy_env.section2_np(rob[i, 0], ball[i], wp.ball.radius, corners, params.camera)
            d = np.abs(o - obs[i])
            assert np.all(d < tol), f"NumPy baseline features differ from JAX: {o} vs {obs[i]}"
            err_obs = max(err_obs, float(np.max(d / tol * 1e-4)))
            e = max(np.max(np.abs(np.array(s_np[i]["ball"]) - ball[i])),
                    np.max(np.abs(np.array(s_np[i]["robots"])[0, :2] - rob[i, 0, :2])))
            assert e < 1e-4, f"NumPy baseline world differs from JAX by {e} m"
            err_pos = max(err_pos, float(e))
    return dict(episodes=n, steps=steps, max_rel_feature_err=err_obs, max_pos_err_m=err_pos)


def time_oracle(env, params, seconds, with_camera):
    """Test oracles (world_np + brute-force camera_np) episode by episode, random actions."""
    rng = np.random.default_rng(0)
    wp = params.world
    corners = world_np.goal_corners_np(wp)
    starts = draw_starts(env, params, 256)
    n_steps = n_ep = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        st = starts[n_ep % 256]
        s = dict(robots=[st["robots"]], ball=st["ball"], vel=[0.0, 0.0], scored=False,
                 out=False)
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
    ap.add_argument("--devices", type=int, default=1,
                    help="also run with the batch split over this many forced CPU devices")
    ap.add_argument("--prng", default="threefry2x32",
                    help="jax PRNG implementation of the keys (threefry2x32, rbg, unsafe_rbg)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "env_throughput"))
    args = ap.parse_args(argv)
    batches = args.batches or ([1, 64, 4096] if args.quick else [1, 16, 256, 4096, 65536])
    target_steps = 2**18 if args.quick else 2**21
    env = ShootingEnv()
    params = env.default_params
    agree = check_numpy_env(env, params, n=16 if args.quick else 64)
    print(f"NumPy baseline agrees with the JAX env: {agree}", flush=True)
    rows = []
    for b in batches:
        steps = int(min(max(target_steps // b, 20), 2000 if args.quick else 5000))
        for n_dev in sorted({1, args.devices}):
            if b % n_dev:
                continue
            row = time_jax(env, params, b, steps, args.reps, n_dev, args.prng)
            rows.append(row)
            print(f"batch {b:6d} devices {n_dev}: {row['steps_per_s'] / 1e6:8.3f} M steps/s "
                  f"(T={steps}, compile {row['compile_s']:.1f} s)", flush=True)
    ref_s = 5.0 if args.quick else 20.0
    base = numpy_env.run_episodes(draw_starts(env, params, 256), params, env.num_actions, ref_s)
    oracle = time_oracle(env, params, 3.0 if args.quick else 10.0, with_camera=True)
    print(f"NumPy baseline (world + closed-form features): {base['steps_per_s']:.1f} steps/s; "
          f"test oracle (world_np + brute-force camera_np): {oracle['steps_per_s']:.1f} steps/s")
    for r in rows:
        r["speedup_vs_numpy"] = r["steps_per_s"] / base["steps_per_s"]
        r["speedup_vs_oracle"] = r["steps_per_s"] / oracle["steps_per_s"]
    hw = dict(cpu=cpu_model(), cores=os.cpu_count(), jax=jax.__version__,
              devices=[str(d) for d in jax.devices()], python=platform.python_version(),
              xla_flags=os.environ.get("XLA_FLAGS", ""), load_avg=os.getloadavg())
    result = dict(benchmark="env_throughput", env="ShootingEnv(two_motor)",
                  substeps=params.world.substeps, quick=args.quick, hardware=hw, jax=rows,
                  numpy_baseline=base, numpy_baseline_check=agree, test_oracle=oracle,
                  targets=dict(steps_per_s_at_4096=5e6, speedup=300))
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=2))
    cmd = "python benchmarks/env_throughput.py" + (" --quick" if args.quick else "") + (
        f" --devices {args.devices}" if args.devices > 1 else "")
    lines = [f"Shooting env throughput ({hw['cpu']}, {hw['cores']} cores, jax {hw['jax']}, "
             f"PRNG {args.prng}, load average {hw['load_avg'][0]:.1f} at the end; `{cmd}`)", "",
             "| batch | devices | env steps/s | x NumPy baseline | x test oracle | compile s |",
             "|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['batch']:,} | {r['devices']} | {r['steps_per_s']:,.0f} | "
                     f"{r['speedup_vs_numpy']:,.0f} | {r['speedup_vs_oracle']:,.0f} | "
                     f"{r['compile_s']:.0f} |")
    lines += ["", f"NumPy baseline (`benchmarks/numpy_env.py`: closed-form world + Section 2 "
              f"features, episode by episode): {base['steps_per_s']:,.0f} steps/s; test oracle "
              f"(`tests/reference`, brute-force camera): {oracle['steps_per_s']:,.1f} steps/s. "
              "`compile s` is the first call (trace + compile + one run); the persistent "
              "compilation cache of `vbl` (`VBL_JAX_CACHE`) can shorten it. The machine is "
              "shared: compare rows of one run, not absolute numbers across runs.", ""]
    out.with_suffix(".md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
