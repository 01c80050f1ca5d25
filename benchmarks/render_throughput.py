"""Render throughput: camera images per second from ``vbl.vision.render`` and pixel
features per second (render + ``vbl.vision.blobs``), beside the analytic features of
``vbl.vision.section3`` on the same scenes, at several image sizes and batch sizes.

Scenes: :func:`vbl.vision.scenes.random_scenes`, the kinds in turn (close, far, cut by the
borders, occluded, lost), the other robot drawn as the Section 3 camera's box. Each timed
program is ``T`` calls of ``vmap(f)`` in a ``lax.scan`` (jit-compiled); call ``i`` turns
every robot by ``i * 1e-4`` rad (so XLA cannot hoist the work out of the loop) and every
output is folded into the carry (the images' pixel sum, the features' sum), so nothing is
dropped. Rows:

* ``render``: the camera image (uint8, H x W x 3) per frame;
* ``pixel features``: the image and its Section 3 feature vector from pixels
  (:func:`vbl.vision.blobs.section3_flat_from_pixels`) per frame;
* ``analytic``: the Section 3 vector of the analytic camera per frame (no image).

Timing (the persistent compilation cache off unless ``VBL_JAX_CACHE`` says otherwise):
``compile s`` is the first call (trace + compile + one run); then best of ``--reps`` of
process CPU time and wall time with ``block_until_ready``. ``T`` is chosen so that a timed
run covers about ``--pixels`` pixels (at least one call). Combinations whose working set
(:func:`working_set_gb`) exceeds ``--max-gb`` are skipped and listed as skipped. The
machine is shared: read the ratio of two rows of one run, not absolute figures across runs.

Usage::

    python benchmarks/render_throughput.py            # batches 1..1,024, 3 sizes
    python benchmarks/render_throughput.py --quick    # batches 1, 16, 256, fewer pixels
    python benchmarks/render_throughput.py --tiny     # smoke test: 16 x 15, batch 1
Writes benchmarks/results/render_throughput.{json,md} (``--out`` elsewhere).
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
# compile times are measured, so the persistent compilation cache of vbl is off by default
os.environ.setdefault("VBL_JAX_CACHE", "off")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import vbl  # noqa: E402,F401
from benchmarks.camera_throughput import make_runner  # noqa: E402
from benchmarks.hardware import hardware_info, write_results  # noqa: E402
from vbl.vision.blobs import BlobParams, section3_flat_from_pixels  # noqa: E402
from vbl.vision.camera import CameraParams  # noqa: E402
from vbl.vision.render import RenderParams, render_camera, to_uint8  # noqa: E402
from vbl.vision.scenes import OTHER_HEIGHT, SCENE_KINDS, random_scenes  # noqa: E402
from vbl.vision.section3 import flatten_section3, section3_features  # noqa: E402
from vbl.world import WorldParams, goal_corners  # noqa: E402

#: Image sizes (width, height): the learners' small images and the paper's 512 x 480.
SIZES = ((64, 60), (128, 120), (512, 480))
BATCHES = (1, 4, 16, 64, 256, 1024)
QUICK_BATCHES = (1, 16, 256)
#: Working set per pixel of a frame, bytes: the peak resident memory of the pixel
#: features program grew by about 75 bytes per pixel from batch 8 to batch 32 at
#: 512 x 480 (the uint8 image, the three float32 colour masks the blob features store,
#: and the ray caster's and the reductions' temporaries), rounded up.
BYTES_PER_PIXEL = 80
#: Skip combinations whose working set exceeds this, GB (default; ``--max-gb``): at
#: 512 x 480, batches above 64 are skipped.
MAX_GB = 3.0
F32 = jnp.float32
ROWS = ("render", "pixel features", "analytic")


def working_set_gb(batch: int, width: int, height: int) -> float:
    """Estimated memory of one batched call, GB (``BYTES_PER_PIXEL`` per pixel)."""
    return batch * width * height * BYTES_PER_PIXEL / 1e9


def scenes(batch: int) -> dict:
    """``batch`` scenes, the kinds of :data:`SCENE_KINDS` in turn: pose, ball, other."""
    per = -(-batch // len(SCENE_KINDS))
    parts = [random_scenes(per, k, seed=i) for i, k in enumerate(SCENE_KINDS)]
    out = {}
    for key in ("pose", "ball", "other"):
        stacked = np.stack([p[key] for p in parts], axis=1).reshape(per * len(SCENE_KINDS), -1)
        out[key] = jnp.asarray(stacked[:batch])
    return out


def frame_fn(row: str, width: int, height: int):
    """(pose, ball, other) -> one float32 checksum of the row's outputs for one frame."""
    world, cam, bp = WorldParams(), CameraParams(), BlobParams()
    rp = RenderParams(width=width, height=height)
    gc, r = goal_corners(world), jnp.asarray(world.ball.radius, F32)
    size = jnp.asarray([2 * world.robot.radius, 2 * world.robot.radius, OTHER_HEIGHT], F32)

    def image(pose, ball, other):
        return to_uint8(render_camera(pose, ball, r, gc, world.field, cam, rp, other, size))

    if row == "render":
        return lambda p, b, o: jnp.sum(image(p, b, o).astype(F32))
    if row == "pixel features":
        return lambda p, b, o: jnp.sum(section3_flat_from_pixels(image(p, b, o), cam, bp))
    return lambda p, b, o: jnp.sum(flatten_section3(
        section3_features(p, b, r, gc, o, size, cam)))


def time_row(row: str, width: int, height: int, s: dict, pixels: float, reps: int) -> dict:
    """Frames per second of one row at one size and batch (see the module docstring)."""
    batch = s["pose"].shape[0]
    calls = max(1, round(pixels / (batch * width * height)))
    run = make_runner(jax.vmap(frame_fn(row, width, height)), calls)
    args = (s["pose"], s["ball"], s["other"])
    t0 = time.perf_counter()
    jax.block_until_ready(run(*args))
    compile_s = time.perf_counter() - t0
    wall = cpu = np.inf
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        acc = jax.block_until_ready(run(*args))
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    if not np.isfinite(float(acc)):
        raise RuntimeError(f"non-finite output of {row}")
    n = batch * calls
    return dict(row=row, size=f"{width}x{height}", width=width, height=height, batch=batch,
                calls=calls, frames_per_s=n / wall, cpu_us_per_frame=cpu / n * 1e6,
                wall_us_per_frame=wall / n * 1e6, compile_s=compile_s)


def markdown(result: dict, cmd: str) -> str:
    hw = result["hardware"]
    lines = [f"Render throughput ({hw['cpu']}, {hw['cores']} cores, jax {hw['jax']}, load "
             f"average {hw['load_average']:.1f} at the start and {result['load_end']:.1f} at "
             f"the end; `{cmd}`). Frames per second (wall) of the camera image alone, of the "
             "image and its Section 3 features from pixels, and of the analytic Section 3 "
             "features, same scenes, same run.", "",
             "| size | batch | render frames/s | pixel features/s | analytic features/s | "
             "render CPU us/frame | pixel features CPU us/frame | analytic CPU us/frame | "
             "compile s (render, pixels, analytic) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    by = {}
    for r in result["rows"]:
        by.setdefault((r["size"], r["batch"]), {})[r["row"]] = r
    for (size, batch), rows in by.items():
        cells = [rows.get(k) for k in ROWS]
        fps = [f"{c['frames_per_s']:,.0f}" if c else "-" for c in cells]
        cpu = [f"{c['cpu_us_per_frame']:,.1f}" if c else "-" for c in cells]
        comp = ", ".join(f"{c['compile_s']:.1f}" if c else "-" for c in cells)
        lines.append(f"| {size} | {batch:,} | {' | '.join(fps)} | {' | '.join(cpu)} | {comp} |")
    lines += ["", "CPU us/frame is process CPU time per frame (all threads), after warm-up, "
              "best of the repetitions; frames/s is from the best wall time."]
    if result["skipped"]:
        lines += ["", "Skipped (working set above "
                  f"{result['max_gb']:g} GB, estimated at {BYTES_PER_PIXEL} bytes per pixel): "
                  + ", ".join(f"{s['size']} at batch {s['batch']:,} ({s['gb']:.1f} GB)"
                              for s in result["skipped"]) + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="batches 1, 16, 256; fewer pixels")
    ap.add_argument("--tiny", action="store_true", help="smoke test: 16 x 15 images, "
                    "batch 1, one repetition")
    ap.add_argument("--batches", type=int, nargs="+", default=None)
    ap.add_argument("--pixels", type=float, default=None,
                    help="pixels per timed run (default 2^27, --quick 2^25)")
    ap.add_argument("--reps", type=int, default=None)
    ap.add_argument("--max-gb", type=float, default=MAX_GB)
    ap.add_argument("--rows", nargs="+", choices=ROWS, default=list(ROWS),
                    help="which programs to time (default all)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "render_throughput"))
    args = ap.parse_args(argv)
    sizes = ((16, 15),) if args.tiny else SIZES
    batches = args.batches or ((1,) if args.tiny else QUICK_BATCHES if args.quick
                               else BATCHES)
    pixels = args.pixels or (2.0 ** 10 if args.tiny else 2.0 ** 25 if args.quick
                             else 2.0 ** 27)
    reps = args.reps or (1 if args.tiny else 3)
    result = dict(benchmark="render_throughput", quick=args.quick, tiny=args.tiny,
                  hardware=hardware_info(), max_gb=args.max_gb, rows=[], skipped=[])
    for batch in batches:
        s = scenes(batch)
        for width, height in sizes:
            gb = working_set_gb(batch, width, height)
            if gb > args.max_gb:
                result["skipped"].append(dict(size=f"{width}x{height}", batch=batch, gb=gb))
                print(f"{width}x{height} batch {batch}: skipped ({gb:.1f} GB)", flush=True)
                continue
            for row in args.rows:
                r = time_row(row, width, height, s, pixels, reps)
                result["rows"].append(r)
                print(f"{r['size']} batch {batch} {row}: {r['frames_per_s']:,.0f} frames/s, "
                      f"{r['cpu_us_per_frame']:.1f} CPU us/frame (compile {r['compile_s']:.1f}"
                      " s)", flush=True)
    result["rows"].sort(key=lambda r: (r["width"] * r["height"], r["batch"]))
    result["load_end"] = os.getloadavg()[0]
    out = pathlib.Path(args.out)
    cmd = "python benchmarks/render_throughput.py" + (" --quick" if args.quick else "")
    text = markdown(result, cmd)
    write_results(out, result, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
