"""Probe: pixel collection cost, the CPU time per frame of identification-data collection
(:func:`vbl.envs.collect.collect_many`) from the analytic features and from the rendered
camera image through the colour-blob detector (``obs_source="pixels"``, 128 x 120 images),
without and with image noise (``noise.pixel_std`` of :data:`vbl.envs.noise.NOISE_ON_PIXELS`).

One scenario (Table 1's ball row: the observer keeps the ball in view, the other robot
stands), ``--batch`` data sets of ``--steps`` frames in one compiled call, as Table 3's
collection runs them. ``compile s`` is the first call (trace + compile + one run; the
noisy row reuses the noise-free row's program), then the best of ``--reps`` calls with
other keys: process CPU time (all threads) and wall time per frame. Compare the pixel
rows with ``render_throughput.md``'s pixel features per frame (the image and its blob
features alone) plus one frame's image-noise normals, which the two ``part`` rows time
alone (in a ``lax.scan`` of ``--steps`` steps over ``--batch`` frames, outputs summed; the
image of the collection's start worlds, the camera turned a little each step). The machine
is shared: read the ratio of two rows of one run, not absolute figures across runs.

Usage::

    python benchmarks/probes/pixel_collection_cost.py          # batch 16, 100 steps
    python benchmarks/probes/pixel_collection_cost.py --tiny   # smoke test: batch 1, 4 steps

Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import vbl  # noqa: E402,F401
from benchmarks.hardware import hardware_info  # noqa: E402
from vbl.envs.collect import CollectParams, _start, collect_many  # noqa: E402
from vbl.envs.noise import NOISE_ON_PIXELS  # noqa: E402
from vbl.envs.pixels import image_noise_shape, section3_pixels  # noqa: E402

#: The collection rows: (name, obs_source, image noise on).
ROWS = (("analytic", "analytic", False), ("pixels, noise-free", "pixels", False),
        ("pixels, image noise", "pixels", True))
#: The parts of a pixel frame, alone.
PARTS = ("part: image + blob features", "part: image-noise normals")


def _cpu() -> float:
    return time.process_time()


def time_row(obs_source: str, noisy: bool, batch: int, steps: int, reps: int) -> dict:
    """Compile time (s) and best CPU / wall time per frame (us) of one collection call."""
    p = CollectParams(num_steps=steps, focus="ball", other_behaviour="stationary",
                      obs_source=obs_source)
    if noisy:
        p = p.replace(noise=NOISE_ON_PIXELS)
    return _timed(lambda r: collect_many(jax.random.PRNGKey(r), [p], batch), batch * steps,
                  reps)


def _timed(call, frames: int, reps: int) -> dict:
    """``call(0)`` (compile), then the best of ``call(1..reps)`` per frame."""
    t0 = time.perf_counter()
    jax.block_until_ready(call(0))
    compile_s = time.perf_counter() - t0
    cpu, wall = [], []
    for r in range(reps):
        c0, w0 = _cpu(), time.perf_counter()
        jax.block_until_ready(call(r + 1))
        cpu.append(_cpu() - c0)
        wall.append(time.perf_counter() - w0)
    return dict(compile_s=compile_s, cpu_us_per_frame=1e6 * min(cpu) / frames,
                wall_us_per_frame=1e6 * min(wall) / frames)


def _part(name: str, p: CollectParams, batch: int, steps: int):
    """A jitted function of a key: ``steps`` x ``batch`` frames of one part of a pixel
    frame (the image and its Section 3 blob features of the collection's start worlds,
    turned a little each step, or one frame's image-noise normals), outputs summed."""
    def part(key):
        k_start, k_run = jax.random.split(key)
        worlds = jax.vmap(lambda k: _start(jax.random.uniform(k, (6,)), p))(
            jax.random.split(k_start, batch))

        def frame(w, k, t):
            if name == PARTS[1]:
                return jnp.sum(jax.random.normal(k, image_noise_shape(p.pixels)))
            w = w.replace(robots=w.robots.at[0, 2].add(1e-3 * t))
            return jnp.sum(section3_pixels(w, 0, p.camera, p.world, p.noise, p.robot_height,
                                           0.0, p.pixels, None))

        def body(c, xs):
            t, ks = xs
            return c + jnp.sum(jax.vmap(frame, (0, 0, None))(worlds, ks, t)), None

        keys = jax.random.split(k_run, (steps, batch))
        return jax.lax.scan(body, 0.0, (jnp.arange(steps, dtype=jnp.float32), keys))[0]
    return jax.jit(part)


def time_part(name: str, batch: int, steps: int, reps: int) -> dict:
    """:func:`time_row` of one part (:data:`PARTS`) of a pixel frame."""
    p = CollectParams(num_steps=steps, focus="ball", other_behaviour="stationary",
                      obs_source="pixels")
    f = _part(name, p, batch, steps)
    return _timed(lambda r: f(jax.random.PRNGKey(r)), batch * steps, reps)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=16, help="data sets per call")
    ap.add_argument("--steps", type=int, default=100, help="frames per data set")
    ap.add_argument("--reps", type=int, default=3, help="timed calls (best is kept)")
    ap.add_argument("--tiny", action="store_true", help="smoke test: batch 1, 4 steps, 1 rep")
    a = ap.parse_args(argv)
    if a.tiny:
        a.batch, a.steps, a.reps = 1, 4, 1
    hw = hardware_info()
    rows = {name: time_row(src, noisy, a.batch, a.steps, a.reps) for name, src, noisy in ROWS}
    rows |= {name: time_part(name, a.batch, a.steps, a.reps) for name in PARTS}
    hw_end = hardware_info()
    load = f"{hw['load_average']:.1f} at the start and {hw_end['load_average']:.1f} at the end"
    lines = [f"Pixel collection ({hw['cpu']}, {hw['cores']} cores, jax {hw['jax']}, load "
             f"average {load}; `python benchmarks/probes/pixel_collection_cost.py --batch "
             f"{a.batch} --steps {a.steps}`): `collect_many` of one scenario, {a.batch} data "
             f"sets of {a.steps} frames per call, 128 x 120 images for the pixel rows.", "",
             "| row | CPU us/frame | wall us/frame | compile s |", "|---|---:|---:|---:|"]
    for name, r in rows.items():
        lines.append(f"| {name} | {r['cpu_us_per_frame']:,.1f} | {r['wall_us_per_frame']:,.1f} "
                     f"| {r['compile_s']:.1f} |")
    lines += ["", "CPU us/frame is process CPU time per frame (all threads), best of "
              f"{a.reps} calls after the first; wall likewise."]
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
