"""Camera throughput: CPU time per call per env of the Section 2 and Section 3 cameras,
the current ``vbl.vision`` against an earlier single-module camera in the same run.

The earlier version is read from git (``--old-rev``, default: the last commit with the
face-by-face polygon clipping camera) and loaded as a module beside the current one. Both
run the same scenes: start states of ``ShootPassEnv("shoot")`` (Section 3: the shooter's
camera sees the ball, the goal and the passer) and of ``ShootingEnv`` (Section 2), batch
``--batch``. Each timed program is ``T`` calls of ``vmap(camera)`` in a ``lax.scan``; call
``i`` turns every robot by ``i * 1e-4`` rad (so XLA cannot hoist the camera out of the
loop) and the sum of every output is folded into the carry (so it cannot drop any of it).
Timing (the persistent compilation cache off unless ``VBL_JAX_CACHE`` says otherwise):
after a warm-up call, best of ``--reps`` of process CPU time (``time.process_time``)
and wall time with ``block_until_ready``; ``compile s`` is the first call (trace + compile
+ one run). The machine is shared: read the ratio of two rows of one run, not absolute
figures across runs.

Usage::

    python benchmarks/camera_throughput.py            # batch 4096
    python benchmarks/camera_throughput.py --quick    # batch 1024, fewer calls
    python benchmarks/camera_throughput.py --trace    # where the Section 3 camera's time goes
Writes benchmarks/results/camera_throughput.{json,md} (``--out`` elsewhere); ``--trace``
writes nothing: it prints the time of the current Section 3 camera per part of its compiled
program (:func:`trace_breakdown`).
"""

from __future__ import annotations

import argparse
import collections
import gzip
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time
import types

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
# compile times are measured, so the persistent compilation cache of vbl is off by default
os.environ.setdefault("VBL_JAX_CACHE", "off")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import vbl  # noqa: E402,F401
import vbl.vision as new_features  # noqa: E402
from benchmarks.hardware import hardware_info, write_results  # noqa: E402
from vbl.envs.shoot_pass import ShootPassEnv  # noqa: E402
from vbl.envs.shooting import ShootingEnv  # noqa: E402
from vbl.world.physics import goal_corners  # noqa: E402

#: Last commit whose camera clips each box face and each goal occluder polygon separately.
OLD_REV = "9681a38"
#: Heading change per call inside the timed scan, rad (defeats loop-invariant hoisting).
TURN_PER_CALL = 1e-4
F32 = jnp.float32
#: The Section 3 camera's ``lax.scan``s by trip count (docs/vision.md, "Exactness and cost").
SCANS = {4: "goal segments: near clip, projection, image clip (4 steps)",
         5: "goal boundary in 4 boxes: Green sums (5 steps)",
         9: "robot boundary in 2 boxes: Green sums (9 steps)",
         12: "robot box edges: near clip, projection (12 steps)"}


def load_old(rev: str) -> types.ModuleType:
    """The single-module camera ``vbl/vision/features.py`` at git revision ``rev`` as a module."""
    src = subprocess.run(["git", "show", f"{rev}:vbl/vision/features.py"], cwd=ROOT,
                         check=True, capture_output=True, text=True).stdout
    mod = types.ModuleType("vbl_features_old")
    mod.__file__ = f"{rev}:vbl/vision/features.py"
    sys.modules[mod.__name__] = mod
    exec(compile(src, mod.__file__, "exec"), mod.__dict__)
    return mod


def scenes(batch: int) -> dict:
    """Start states of both envs: poses, ball, goal corners, other robot, cameras."""
    sp = ShootPassEnv("shoot")
    p3 = sp.default_params
    w3 = jax.vmap(sp.sample_start, (0, None))(jax.random.split(jax.random.key(1), batch), p3)
    sh = ShootingEnv()
    p2 = sh.default_params
    w2 = jax.vmap(sh.sample_start, (0, None))(jax.random.split(jax.random.key(2), batch), p2)
    d = 2 * p3.world.robot.radius
    return dict(
        section3=dict(pose=w3.robots[:, 0], ball=w3.ball, other=w3.robots[:, 1],
                  radius=jnp.asarray(p3.world.ball.radius, F32),
                  goal=goal_corners(p3.world), size=jnp.asarray([d, d, p3.robot_height], F32),
                  cam=p3.shooter_camera),
        section2=dict(pose=w2.robots[:, 0], ball=w2.ball,
                  radius=jnp.asarray(p2.world.ball.radius, F32),
                  goal=goal_corners(p2.world), cam=p2.camera))


def camera_fn(mod, section: int, s: dict):
    """(pose (B,3), ball (B,2), other (B,3)) -> outputs (B, n) float32 of one camera."""
    if section == 3:
        def one(pose, ball, other):
            return mod.flatten_section3(mod.section3_features(
                pose, ball, s["radius"], s["goal"], other, s["size"], s["cam"]))
    else:
        def one(pose, ball, other):
            return mod.section2_features(pose, ball, s["radius"], s["goal"], s["cam"])
    return jax.vmap(one)


def make_runner(fn, calls: int):
    """Compiled ``run(pose, ball, other) -> sum of all outputs`` over ``calls`` calls."""
    def run(pose, ball, other):
        def body(acc, i):
            turn = jnp.stack([0.0, 0.0, TURN_PER_CALL]).astype(F32) * i.astype(F32)
            return acc + jnp.sum(fn(pose + turn, ball, other + turn)), None

        acc, _ = jax.lax.scan(body, jnp.zeros((), F32), jnp.arange(calls, dtype=jnp.int32))
        return acc

    return jax.jit(run)


def time_camera(mod, section: int, s: dict, calls: int, reps: int) -> dict:
    batch = s["pose"].shape[0]
    other = s.get("other", s["pose"])
    run = make_runner(camera_fn(mod, section, s), calls)
    t0 = time.perf_counter()
    jax.block_until_ready(run(s["pose"], s["ball"], other))
    compile_s = time.perf_counter() - t0
    wall = cpu = np.inf
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        acc = jax.block_until_ready(run(s["pose"], s["ball"], other))
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    if not np.isfinite(float(acc)):
        raise RuntimeError("non-finite camera output")
    n = batch * calls
    return dict(batch=batch, calls=calls, cpu_us_per_call=cpu / n * 1e6,
                wall_us_per_call=wall / n * 1e6, calls_per_s=n / wall, compile_s=compile_s)


def agreement(old, new, section: int, s: dict) -> float:
    """Largest |old - new| over the scenes' outputs (px, px^2, flags)."""
    other = s.get("other", s["pose"])
    a = jax.jit(camera_fn(old, section, s))(s["pose"], s["ball"], other)
    b = jax.jit(camera_fn(new, section, s))(s["pose"], s["ball"], other)
    return float(jnp.max(jnp.abs(a - b)))


def markdown(result, cmd) -> str:
    hw = result["hardware"]
    lines = [f"Camera throughput ({hw['cpu']}, {hw['cores']} cores, jax {hw['jax']}, load "
             f"average {hw['load_average']:.1f} at the start and {result['load_end']:.1f} at "
             f"the end; `{cmd}`). Old = `vbl/vision/features.py` at `{result['old_rev']}`, "
             f"new = the current one, same scenes, same run.", "",
             "| camera | version | batch | CPU us/call | wall us/call | calls/s | compile s "
             "|", "|---|---|---:|---:|---:|---:|---:|"]
    for name, rows in result["cameras"].items():
        for ver in ("old", "new"):
            r = rows[ver]
            lines.append(f"| {name} | {ver} | {r['batch']:,} | {r['cpu_us_per_call']:.3f} | "
                         f"{r['wall_us_per_call']:.3f} | {r['calls_per_s']:,.0f} | "
                         f"{r['compile_s']:.1f} |")
    lines += [""]
    for name, rows in result["cameras"].items():
        lines.append(f"* {name}: new / old CPU time = {rows['cpu_ratio']:.3f} "
                     f"({1 / rows['cpu_ratio']:.1f}x faster); largest |old - new| output "
                     f"difference on the benchmark scenes {rows['max_abs_diff']:.3g}.")
    lines += ["", "CPU us/call is process CPU time per camera call per env (all threads), "
              "after warm-up, best of the repetitions.", ""]
    return "\n".join(lines)


def trace_breakdown(s: dict, calls: int) -> dict[str, float]:
    """Thread time (us per call per env) of each part of the current Section 3 camera.

    One warmed-up run of the timed program under ``jax.profiler.trace``; the XLA CPU
    runtime records every executed kernel (thunk). A kernel that runs ``calls`` times is
    the camera's straight-line code; one that runs ``calls * k`` times belongs to the scan
    of ``k`` steps (:data:`SCANS`); host-side spans (dispatch, buffers) are left out.
    Durations are wall time on the executing thread, so a
    loaded machine inflates all parts alike: read the shares.
    """
    batch = s["pose"].shape[0]
    args = (s["pose"], s["ball"], s["other"])
    run = make_runner(camera_fn(new_features, 3, s), calls)
    jax.block_until_ready(run(*args))
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            jax.block_until_ready(run(*args))
        path = next(pathlib.Path(tmp).rglob("perfetto_trace.json.gz"))
        events = json.loads(gzip.decompress(path.read_bytes()))["traceEvents"]
    dur, count = collections.Counter(), collections.Counter()
    for e in events:
        name = e.get("name", "")
        if e.get("ph") == "X" and not name.startswith(("$", "Thunk", "while")):
            dur[name] += e.get("dur", 0.0)
            count[name] += 1
    parts = collections.Counter()
    for name, us in dur.items():
        k, rest = divmod(count[name], calls)
        if rest or not k:   # host-side runtime spans of the one timed call, not kernels
            continue
        part = "straight-line code (one pass per call)" if k == 1 else SCANS.get(
            k, "other kernels")
        parts[part] += us / (calls * batch)
    return dict(parts.most_common())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="batch 1024, fewer calls")
    ap.add_argument("--batch", type=int, default=None)
    ap.add_argument("--calls", type=int, default=None, help="camera calls per timed run")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--old-rev", default=OLD_REV)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "camera_throughput"))
    ap.add_argument("--trace", action="store_true", help="print where the current Section 3 "
                    "camera's time goes (profiler trace) and exit")
    args = ap.parse_args(argv)
    batch = args.batch or (1024 if args.quick else 4096)
    calls = args.calls or (20 if args.quick else 50)
    if args.trace:
        parts = trace_breakdown(scenes(batch)["section3"], calls)
        print(f"Section 3 camera, batch {batch}, thread us per call per env (load average "
              f"{os.getloadavg()[0]:.1f}):")
        for part, us in parts.items():
            print(f"  {us:6.3f}  {part}")
        print(f"  {sum(parts.values()):6.3f}  total")
        return
    old = load_old(args.old_rev)
    sc = scenes(batch)
    result = dict(benchmark="camera_throughput", quick=args.quick, hardware=hardware_info(),
                  old_rev=args.old_rev, cameras={})
    for name, section in (("section3", 3), ("section2", 2)):
        s = sc[name]
        rows = {}
        for ver, mod in (("old", old), ("new", new_features)):
            rows[ver] = time_camera(mod, section, s, calls, args.reps)
            r = rows[ver]
            print(f"{name} {ver}: {r['cpu_us_per_call']:.3f} CPU us/call, "
                  f"{r['wall_us_per_call']:.3f} wall us/call (compile {r['compile_s']:.1f} s)",
                  flush=True)
        rows["cpu_ratio"] = rows["new"]["cpu_us_per_call"] / rows["old"]["cpu_us_per_call"]
        rows["max_abs_diff"] = agreement(old, new_features, section, s)
        result["cameras"][name] = rows
    result["load_end"] = os.getloadavg()[0]
    out = pathlib.Path(args.out)
    cmd = "python benchmarks/camera_throughput.py" + (" --quick" if args.quick else "")
    text = markdown(result, cmd)
    write_results(out, result, text)
    print(text)


if __name__ == "__main__":
    main()
