"""Probe: the camera of this checkout against the camera of an earlier commit, same run.

What it measures, for the single-module camera ``vbl/vision/features.py`` at ``--base REV``
(read with ``git show`` and loaded beside the current package) and for the working tree:

* each camera alone (Section 3 on ``ShootPassEnv("shoot")`` start states, Section 2 on
  ``ShootingEnv`` start states, batch ``--batch``): CPU us per call per env, the two
  versions alternating for ``--reps`` rounds (min and median: the machine is shared);
* the two-robot env step with its observation consumed (``ShootPassEnv("shoot")``, random
  actions, auto-reset; the env's camera swapped for the base one on the base side): CPU
  us per env step and the compile time of the step program;
* agreement: the largest |base - this| of every Section 3 / Section 2 output on
  ``--scenes`` random scenes (poses anywhere on the field, half of them with the other
  robot and the ball 0.2-1.5 m in front of the camera), px for image coordinates and
  sizes, relative for areas, and the number of scenes whose visibility flags differ.

Not an experiment and not a benchmark (``vbl bench`` reads ``benchmarks/*.py`` only). Run
from the repository root:

    python benchmarks/probes/camera_ab.py --base 47bedbe [--batch 4096] [--reps 15]
        [--scenes 100000] [--tiny]

``--tiny`` (a smoke test: batch 8, 1 alternation, 64 scenes) checks that the probe runs;
its timings mean little.

Cost: about 5 CPU-minutes at the defaults (compilation of 6 programs). Cited by
docs/vision.md ("Exactness and cost").
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
# compile times are measured, so the persistent compilation cache of vbl is off by default
os.environ.setdefault("VBL_JAX_CACHE", "off")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vbl.vision as this_features  # noqa: E402
from benchmarks.camera_throughput import camera_fn, load_old, make_runner, scenes  # noqa: E402
from vbl.envs.shoot_pass import ShootPassEnv  # noqa: E402
from vbl.vision import section3  # noqa: E402
from vbl.vision.camera import CameraParams  # noqa: E402

F32 = jnp.float32
#: Camera calls (env steps) per timed program.
CALLS = 10
#: Section 3 output columns that are areas (goal, other robot), compared relatively.
SEC3_AREAS = [14, 19]
#: Section 3 output columns that are flags (visible, lost side).
SEC3_FLAGS = list(range(20, 26))


def timed(fn, *args) -> float:
    """Process CPU seconds of one blocking call."""
    c0 = time.process_time()
    jax.block_until_ready(fn(*args))
    return time.process_time() - c0


def camera_rows(base, batch: int, reps: int) -> list[str]:
    rows = []
    sc = scenes(batch)
    for name, section in (("section3", 3), ("section2", 2)):
        s = sc[name]
        args = (s["pose"], s["ball"], s.get("other", s["pose"]))
        runs, comp = {}, {}
        for side, mod in (("base", base), ("this", this_features)):
            runs[side] = make_runner(camera_fn(mod, section, s), CALLS)
            t0 = time.perf_counter()
            jax.block_until_ready(runs[side](*args))
            comp[side] = time.perf_counter() - t0
        cpu = {side: [] for side in runs}
        for _ in range(reps):
            for side, run in runs.items():
                cpu[side].append(timed(run, *args) / (batch * CALLS) * 1e6)
        rows.append(row(f"{name} camera", cpu, comp))
    return rows


def env_step_rows(base, batch: int, reps: int) -> list[str]:
    env = ShootPassEnv("shoot")
    p = env.default_params
    _, st0 = jax.jit(jax.vmap(env.reset, (0, None)))(jax.random.split(jax.random.key(0), batch),
                                                      p)

    def make_run():
        """A new function per side: jax.jit caches the trace of a function it has seen."""
        def run(st, k):
            def body(c, i):
                st, acc = c
                ks = jax.random.split(jax.random.fold_in(k, i), batch)
                a = jax.random.randint(jax.random.fold_in(k, -i), (batch,), 0,
                                       env.num_actions)
                o, st, r, *_ = jax.vmap(env.step, (0, 0, 0, None))(ks, st, a, p)
                return (st, acc + o.sum() + r.sum()), None   # every observation consumed
            return jax.lax.scan(body, (st, 0.0), jnp.arange(CALLS))[0][1]
        return run

    saved = (section3.section3_features, section3.flatten_section3)
    runs, comp = {}, {}
    for side, mod in (("base", base), ("this", this_features)):
        # the env imports the camera when it traces its step: swap it for the base side
        section3.section3_features = mod.section3_features
        section3.flatten_section3 = mod.flatten_section3
        try:
            runs[side] = jax.jit(make_run())
            t0 = time.perf_counter()
            jax.block_until_ready(runs[side](st0, jax.random.key(1)))
            comp[side] = time.perf_counter() - t0
        finally:
            section3.section3_features, section3.flatten_section3 = saved
    cpu = {side: [] for side in runs}
    for r in range(reps):
        for side, f in runs.items():
            cpu[side].append(timed(f, st0, jax.random.key(r + 2)) / (batch * CALLS) * 1e6)
    return [row("two-robot env step", cpu, comp)]


def row(name: str, cpu: dict, comp: dict) -> str:
    b, t = np.asarray(cpu["base"]), np.asarray(cpu["this"])
    return (f"| {name} | {b.min():.3f} / {np.median(b):.3f} | {t.min():.3f} / "
            f"{np.median(t):.3f} | {t.min() / b.min():.2f} | {comp['base']:.1f} | "
            f"{comp['this']:.1f} |")


def random_scenes(rng, n: int):
    """Poses anywhere on the field; half the scenes with the other robot and the ball
    0.2-1.5 m in front of the camera (near-plane cuts, border straddles, occlusion)."""
    pose = np.c_[rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(-np.pi, np.pi, n)]
    other = np.c_[rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(-np.pi, np.pi, n)]
    ball = np.c_[rng.uniform(-4, 4, n), rng.uniform(-3, 3, n)]
    close = np.arange(n) % 2 == 1
    ang = pose[:, 2] + rng.uniform(-1.2, 1.2, n)
    dist = rng.uniform(0.2, 1.5, n)
    near_other = pose[:, :2] + dist[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    ang_b = ang + rng.uniform(-0.3, 0.3, n)
    near_ball = pose[:, :2] + (dist * rng.uniform(0.3, 1.5, n))[:, None] * np.c_[
        np.cos(ang_b), np.sin(ang_b)]
    other[close, :2] = near_other[close]
    ball[close] = near_ball[close]
    return (jnp.asarray(pose, F32), jnp.asarray(ball, F32), jnp.asarray(other, F32))


def agreement(base, n: int) -> list[str]:
    cam = CameraParams()
    radius, half_len = 0.11, 8.22 / 2
    goal = jnp.asarray([[half_len, 0.75, 0.0], [half_len, 0.75, 0.5],
                        [half_len, -0.75, 0.5], [half_len, -0.75, 0.0]], F32)
    size = jnp.asarray([0.4, 0.4, 0.3], F32)
    pose, ball, other = random_scenes(np.random.default_rng(0), n)
    out = {}
    for side, mod in (("base", base), ("this", this_features)):
        s3 = jax.jit(jax.vmap(lambda p, b, o, m=mod: m.flatten_section3(m.section3_features(
            p, b, radius, goal, o, size, cam))))
        s2 = jax.jit(jax.vmap(lambda p, b, m=mod: m.section2_features(p, b, radius, goal,
                                                                       cam)))
        out[side] = (np.asarray(s3(pose, ball, other)), np.asarray(s2(pose, ball)))
    (a3, a2), (b3, b2) = out["base"], out["this"]
    d3 = np.abs(a3 - b3)
    px = [c for c in range(20) if c not in SEC3_AREAS]
    rel = d3[:, SEC3_AREAS] / np.maximum(np.abs(a3[:, SEC3_AREAS]), 1.0)
    flags = int(np.any(d3[:, SEC3_FLAGS] > 0, axis=1).sum())
    return [f"* Section 3 on {n:,} random scenes: largest |base - this| of a px feature "
            f"{d3[:, px].max():.3g} px, of an area {d3[:, SEC3_AREAS].max():.3g} px^2 "
            f"(relative {rel.max():.2g}); visibility flags or lost sides differ in {flags} "
            f"scenes.",
            f"* Section 2 on the same scenes: largest |base - this| {np.abs(a2 - b2).max():.3g}"
            f" (px, flags)."]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="git revision to compare with")
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--reps", type=int, default=15, help="alternations of the two sides")
    ap.add_argument("--scenes", type=int, default=100_000, help="random scenes compared")
    ap.add_argument("--tiny", action="store_true",
                    help="smoke-test size: batch 8, 1 alternation, 64 scenes")
    args = ap.parse_args(argv)
    if args.tiny:
        args.batch, args.reps, args.scenes = 8, 1, 64
    base = load_old(args.base)
    load0 = os.getloadavg()[0]
    rows = camera_rows(base, args.batch, args.reps) + env_step_rows(base, args.batch,
                                                                    args.reps)
    notes = agreement(base, args.scenes)
    print(f"CPU us per call per env (camera) or per env step, batch {args.batch}, min / "
          f"median of {args.reps} alternations x {CALLS} calls; compile = first call "
          f"(trace + compile + run), s; load average {load0:.1f} at the start, "
          f"{os.getloadavg()[0]:.1f} at the end; base = {args.base}")
    print("| program | base CPU us (min / median) | this checkout | this / base (min) | "
          "base compile s | this compile s |")
    print("|---|---:|---:|---:|---:|---:|")
    print("\n".join(rows))
    print("\n".join(notes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
