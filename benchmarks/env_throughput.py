"""Env throughput: env steps/s of both vbl tasks, with the observation the learner sees.

For each env (``shooting``: ``ShootingEnv``, one robot, Section 2 features; ``shoot_pass``:
``ShootPassEnv("shoot")``, two robots, scripted passer, Section 3 features) and batch size,
``T`` steps of ``vmap(env.step)`` (auto-reset, random actions drawn inside a ``lax.scan``)
run compiled and warmed up, timed with ``block_until_ready`` (best of ``--reps``, wall
and process CPU time). **Every output is consumed**: the observation, reward and done
flags of every step are folded into the scan carry and returned, so XLA cannot delete the
camera. One extra row per env drops the observation inside the scan (``obs used: no``): that
is what this benchmark measured before it consumed its outputs (a step without its
camera), kept to show the camera's share.

``--devices 2`` also runs each batch split over 2 forced CPU devices (``pmap``; one per
core). Baselines in the same run: ``benchmarks/numpy_env.py`` for the shooting env
(closed-form NumPy world + Section 2 features, episode by episode; checked against the JAX
env first), and for both envs the test oracles' camera (``tests/reference/camera_np``,
brute force), timed per observation.

Usage::

    python benchmarks/env_throughput.py --devices 2   # batches 1..65536
    python benchmarks/env_throughput.py --quick      # about two minutes
Writes benchmarks/results/env_throughput.{json,md} (``--out`` elsewhere).
"""

from __future__ import annotations

import argparse
import os
import pathlib
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
from benchmarks.hardware import hardware_info, write_results  # noqa: E402
from tests.reference import world_np  # noqa: E402
from tests.reference.camera_np import section2_features_np, section3_features_np  # noqa: E402
from vbl.envs.shoot_pass import ShootPassEnv  # noqa: E402
from vbl.envs.shooting import ShootingEnv  # noqa: E402
from vbl.world.physics import goal_corners  # noqa: E402

#: Targets of issue "honest throughput" (2-core CPU): two-robot env step with observation.
TARGETS = dict(shoot_pass_steps_per_s=1e6)

ENVS = dict(shooting=lambda: ShootingEnv(), shoot_pass=lambda: ShootPassEnv("shoot"))


def make_runner(env, params, batch: int, steps: int, n_dev: int = 1, use_obs: bool = True):
    """Compiled ``run(key) -> (obs_sum, reward_sum, done_count)``.

    Batched reset, then ``steps`` auto-resetting steps in a scan. With ``use_obs`` the sum
    of every observation is accumulated in the carry (the camera runs); without, the
    observation is dropped and XLA removes it. With ``n_dev > 1`` the batch is split over
    the devices with ``pmap`` and ``key`` is a (n_dev,) key array.
    """
    n_act = env.num_actions
    local = batch // n_dev

    def run(key):
        k0, k1 = jax.random.split(key)
        obs, state = jax.vmap(env.reset, (0, None))(jax.random.split(k0, local), params)
        acc0 = jnp.sum(obs) if use_obs else jnp.zeros((), jnp.float32)

        def body(carry, _):
            state, key, acc, rew, done = carry
            key, k_act, k_step = jax.random.split(key, 3)
            actions = jax.random.randint(k_act, (local,), 0, n_act, jnp.int32)
            obs, state, reward, _, _, info = jax.vmap(env.step, (0, 0, 0, None))(
                jax.random.split(k_step, local), state, actions, params)
            if use_obs:
                acc = acc + jnp.sum(obs)
            return (state, key, acc, rew + jnp.sum(reward),
                    done + jnp.sum(info["episode_done"], dtype=jnp.int32)), None

        zero = jnp.zeros((), jnp.float32)
        (_, _, acc, rew, done), _ = jax.lax.scan(
            body, (state, k1, acc0, zero, jnp.zeros((), jnp.int32)), None, length=steps)
        return acc, rew, done

    return jax.jit(run) if n_dev == 1 else jax.pmap(run)


def time_jax(env, params, batch, steps, reps, n_dev=1, use_obs=True):
    run = make_runner(env, params, batch, steps, n_dev, use_obs)

    def key(i):
        k = jax.random.key(i)
        return k if n_dev == 1 else jax.random.split(k, n_dev)

    t0 = time.perf_counter()
    jax.block_until_ready(run(key(0)))  # trace + compile + one run
    compile_s = time.perf_counter() - t0
    wall = cpu = np.inf
    for r in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        acc, rew, done = jax.block_until_ready(run(key(r + 1)))
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    if use_obs and not np.all(np.isfinite(np.asarray(acc))):
        raise RuntimeError("non-finite observation sum")
    n = batch * steps
    return dict(batch=batch, steps=steps, devices=n_dev, obs_used=use_obs, seconds=wall,
                steps_per_s=n / wall, cpu_us_per_step=cpu / n * 1e6, compile_s=compile_s,
                rewards=float(np.sum(rew)), episodes_done=int(np.sum(done)))


def draw_starts(env, n):
    st = jax.vmap(env.sample_start, (0, None))(jax.random.split(jax.random.key(0), n),
                                               env.default_params)
    return jax.tree_util.tree_map(np.asarray, st)


def check_numpy_env(env, params, n=64, steps=5):
    """The NumPy baseline agrees with the JAX shooting env: n episodes x ``steps`` steps
    (features to 1e-4 of each feature's range, positions to 1e-4 m). Returns max errors."""
    tol = np.array([512, 512, 480, 512, 2, 1, 1, 1, 1]) * 1e-4
    _, st = jax.vmap(env.reset, (0, None))(jax.random.split(jax.random.key(7), n), params)
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


def time_oracle_camera(name, env, seconds):
    """Observations/s of the test oracle's camera (``tests/reference/camera_np``) on start
    states of ``env``: the per-observation cost of a brute-force NumPy camera."""
    p = env.default_params
    st = draw_starts(env, 64)
    corners = np.asarray(goal_corners(p.world))
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        i = n % 64
        if name == "shooting":
            section2_features_np(st.robots[i, 0], st.ball[i], p.world.ball.radius, corners,
                                 p.camera)
        else:
            d = 2 * p.world.robot.radius
            section3_features_np(st.robots[i, 0], st.ball[i], p.world.ball.radius, corners,
                                 st.robots[i, 1], [d, d, p.robot_height], p.shooter_camera)
        n += 1
    return n / (time.perf_counter() - t0)


def markdown(result, cmd) -> str:
    hw = result["hardware"]
    lines = [f"Env throughput ({hw['cpu']}, {hw['cores']} cores, jax {hw['jax']}, load average "
             f"{hw['load_average']:.1f} at the start and {result['load_end']:.1f} at the end; "
             f"`{cmd}`). Every row consumes the observation unless `obs used` says no.", "",
             "| env | batch | devices | obs used | env steps/s | CPU us/step | x baseline "
             "| compile s |", "|---|---:|---:|:-:|---:|---:|---:|---:|"]
    for name, rows in result["envs"].items():
        for r in rows:
            lines.append(f"| {name} | {r['batch']:,} | {r['devices']} | "
                         f"{'yes' if r['obs_used'] else 'no'} | {r['steps_per_s']:,.0f} | "
                         f"{r['cpu_us_per_step']:.2f} | {r['x_baseline']:,.0f} | "
                         f"{r['compile_s']:.0f} |")
    b = result["baselines"]
    parts = []
    if "shooting" in b:
        parts.append(f"shooting against `benchmarks/numpy_env.py` (closed-form NumPy world + "
                     f"Section 2 features, episode by episode): {b['shooting']:,.0f} steps/s")
    if "shoot_pass" in b:
        parts.append(f"shoot_pass against the test oracle's Section 3 camera alone "
                     f"(`tests/reference/camera_np`, brute force): {b['shoot_pass']:,.1f} "
                     f"observations/s")
    lines += ["", f"Baselines (`x baseline`): {'; '.join(parts)}. Rows with `obs used: no` "
              f"drop the observation, so XLA removes the camera: the figure this benchmark "
              f"reported before it consumed its outputs.", ""]
    if "shoot_pass" in result["envs"]:
        best = max(r["steps_per_s"] for r in result["envs"]["shoot_pass"] if r["obs_used"])
        verdict = "met" if best >= TARGETS["shoot_pass_steps_per_s"] else "not met"
        lines += [f"Target: two-robot step with observation >= "
                  f"{TARGETS['shoot_pass_steps_per_s']:,.0f} steps/s on 2 cores: best "
                  f"{best:,.0f} ({verdict})."]
    lines += ["`compile s` is the first call (trace + compile + one run). The machine is "
              "shared: compare rows of one run.", ""]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, about two minutes")
    ap.add_argument("--batches", type=int, nargs="*", default=None)
    ap.add_argument("--envs", nargs="*", default=list(ENVS), choices=list(ENVS))
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--devices", type=int, default=1,
                    help="also run with the batch split over this many forced CPU devices")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "env_throughput"))
    args = ap.parse_args(argv)
    batches = args.batches or ([64, 4096] if args.quick else [1, 64, 1024, 4096, 16384])
    target_steps = 2**17 if args.quick else 2**20
    hw = hardware_info()
    result = dict(benchmark="env_throughput", quick=args.quick, hardware=hw, envs={},
                  baselines={}, targets=TARGETS)
    for name in args.envs:
        env = ENVS[name]()
        params = env.default_params
        rows = []
        for b in batches:
            steps = int(min(max(target_steps // b, 20), 2000))
            for n_dev in sorted({1, args.devices}):
                if b % n_dev == 0:
                    rows.append(time_jax(env, params, b, steps, args.reps, n_dev))
                    r = rows[-1]
                    print(f"{name} batch {b:6d} devices {n_dev}: {r['steps_per_s'] / 1e6:7.3f} M"
                          f" steps/s, {r['cpu_us_per_step']:.2f} CPU us/step (compile "
                          f"{r['compile_s']:.1f} s)", flush=True)
        b = batches[-1]
        rows.append(time_jax(env, params, b, int(max(target_steps // b, 20)), args.reps,
                             use_obs=False))
        print(f"{name} batch {b} without the observation: "
              f"{rows[-1]['steps_per_s'] / 1e6:.3f} M steps/s", flush=True)
        if name == "shooting":
            result["numpy_baseline_check"] = check_numpy_env(env, params, 16)
            starts = draw_starts(env, 256)
            base = numpy_env.run_episodes(
                [dict(robots=starts.robots[i, 0].tolist(), ball=starts.ball[i].tolist())
                 for i in range(256)], params, env.num_actions, 5.0 if args.quick else 20.0)
            result["baselines"][name] = base["steps_per_s"]
        else:
            result["baselines"][name] = time_oracle_camera(name, env, 3.0 if args.quick else 10)
        for r in rows:
            r["x_baseline"] = r["steps_per_s"] / result["baselines"][name]
        result["envs"][name] = rows
    result["load_end"] = os.getloadavg()[0]
    out = pathlib.Path(args.out)
    cmd = "python benchmarks/env_throughput.py" + (" --quick" if args.quick else "") + (
        f" --devices {args.devices}" if args.devices > 1 else "")
    text = markdown(result, cmd)
    write_results(out, result, text)
    print(text)


if __name__ == "__main__":
    main()
