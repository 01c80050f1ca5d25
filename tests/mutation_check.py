"""Mutation check: do the tests notice realistic bugs in the engine's run folders, merge and
resume, the statistics over seeds, the env base and the pixel pipeline (colour blobs, goal
ends, the renderer's pixels)?

Each mutant is one edit (a snippet of a file and what replaces it) that a person could
make by mistake. The check copies the repository's code and tests to a temporary folder,
runs each mutant's tests there once unmutated (they must pass), then applies each mutant
alone, runs its tests (stopping at the first failure, with a timeout) and restores the
file. A mutant is *caught* when its tests fail (or time out), *survived* when they pass.
The working tree is never touched, so other work in it goes on.

    .venv/bin/python tests/mutation_check.py                 # the default set
    .venv/bin/python tests/mutation_check.py --only stats-ddof merge-unsorted
    .venv/bin/python tests/mutation_check.py --issue         # issue 50's survivors
    .venv/bin/python tests/mutation_check.py --fresh --json fresh.json  # the second set
    .venv/bin/python tests/mutation_check.py --blind --json blind.json  # the third set
    .venv/bin/python tests/mutation_check.py --fourth --list         # the fourth set
    .venv/bin/python tests/mutation_check.py --fifth --list          # the fifth set
    .venv/bin/python tests/mutation_check.py --list
    .venv/bin/python tests/mutation_check.py --json results.json

``--fresh`` runs a second set written from the code alone, before its tests were read; its
score before any test was written for it, and after, is in
``benchmarks/results/mutation_fresh.json`` (from the ``--fresh --json`` command above).
``--blind`` runs a third set written the same way, once the tests had been extended for the
second set's survivors, in parts of the modules neither other set touched; its scores are
the ``blind`` entry of the same file.
``--fourth`` runs a fourth set written from the source alone, without reading any test,
mostly in modules and functions the other three sets leave alone.
``--fifth`` runs a fifth set, also written from the source alone, in lines no other set edits.

Exit status: 0 when every mutant run was caught, 1 when one survived, 2 for a bad mutant
(its snippet is not in its file exactly once) or tests that fail unmutated.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

REPO = Path(__file__).resolve().parents[1]
COPIED = ("vbl", "tests", "experiments", "docs", "benchmarks", "pyproject.toml", "README.md",
          "LICENSE")


class Mutant(NamedTuple):
    name: str
    file: str            #: path in the repository
    old: str             #: snippet that occurs exactly once in ``file``
    new: str             #: what replaces it
    tests: tuple[str, ...]  #: pytest arguments (files or node ids)
    why: str             #: the behaviour it breaks


MERGE_TESTS = ("tests/test_merge_integrity.py", "tests/test_shard_merge.py")
FOLDER_TESTS = ("tests/test_engine_edge_cases.py", "tests/test_run_folder_safety.py",
                "tests/test_cli_processes.py")
RESUME_TESTS = ("tests/test_merge_integrity.py", "tests/test_engine_core.py")
STATS_TESTS = ("tests/test_stats.py", "tests/test_engine_edge_cases.py")
ENV_TESTS = ("tests/test_env_base.py",)

M, RF, RN = "vbl/engine/merge.py", "vbl/engine/runfolder.py", "vbl/engine/runner.py"
ST, EB = "vbl/stats.py", "vbl/envs/base.py"

ENGINE_MUTANTS = [
    # ------------------------------------------------------------------ merge
    Mutant("merge-overlap-off-by-one", M, "        if lo < at:\n", "        if lo < at - 1:\n",
           MERGE_TESTS, "a seed held by two shards is merged twice"),
    Mutant("merge-gap-off-by-one", M, "        if lo > at:\n            break",
           "        if lo > at + 1:\n            break", MERGE_TESTS,
           "a seed missing between two shards goes unnoticed"),
    Mutant("merge-unsorted", M,
           "got = sorted(cells.pop((step, chunk, point), []), key=lambda x: _seeds(x)[0])",
           "got = cells.pop((step, chunk, point), [])", MERGE_TESTS,
           "shards given out of order join their seeds out of order"),
    Mutant("merge-no-commit-check", M, "        if p.commit != first.commit:",
           "        if False:", MERGE_TESTS, "shards of two commits merge"),
    Mutant("merge-resumed-min", M, 'max(num("resumed_from_step"), default=0)',
           'min(num("resumed_from_step"), default=0)', MERGE_TESTS,
           "the merged summary hides that a shard resumed"),
    Mutant("merge-summary-of-any-shard", M, 'summary.get("shard") != sh',
           'summary.get("shard") is None', MERGE_TESTS,
           "a summary.json copied from another shard passes as finished"),
    Mutant("merge-checksum-length-only", M, "        if a != b:\n",
           "        if len(a) != len(b):\n", MERGE_TESTS,
           "an edited metrics line of the same length passes"),
    # ------------------------------------------------------------------ run folders
    Mutant("folder-overwrite-parent-of-cwd", RF, "        if _contains_cwd(path):",
           "        if path.resolve() == Path.cwd().resolve():", FOLDER_TESTS,
           "--overwrite may empty a folder that contains the current folder"),
    Mutant("folder-remove-outside", RF,
           '"/" in n or os.sep in n:\n            continue\n        for p in (path / n, '
           'path / (n + ".tmp")):\n            if p.is_dir() and not p.is_symlink():\n'
           '                shutil.rmtree(p)',
           'False:\n            continue\n        for p in (path / n, '
           'path / (n + ".tmp")):\n            if p.is_dir() and not p.is_symlink():\n'
           '                shutil.rmtree(p)', FOLDER_TESTS,
           "a marker naming ../x makes --overwrite delete outside the folder"),
    Mutant("folder-format-default", RF, 'spec.get("format", 1)',
           'spec.get("format", RUN_FORMAT)', FOLDER_TESTS,
           "a config.json without a format passes as today's"),
    Mutant("folder-shared-lock", RF, "fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)",
           "fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)", FOLDER_TESTS,
           "two runs write one folder at once"),
    Mutant("folder-removable-no-write-check", RF, "os.access(d, os.W_OK | os.X_OK)",
           "os.access(d, os.X_OK)", FOLDER_TESTS,
           "--overwrite starts deleting a folder it cannot finish deleting"),
    Mutant("folder-resume-anything", RF,
           '        if not is_vbl_run(path) and not (path / "config.json").is_file():',
           "        if False:", FOLDER_TESTS, "--resume adopts a folder that holds no run"),
    Mutant("folder-fingerprint-of-itself", RF,
           'body = {k: v for k, v in spec.items() if k != "fingerprint"}',
           "body = dict(spec)", FOLDER_TESTS, "every config.json is refused as edited"),
    Mutant("folder-one-file-is-empty", RF,
           "    if not path.is_dir() or not _entries(path):\n        return",
           "    if not path.is_dir() or len(_entries(path)) <= 1:\n        return",
           FOLDER_TESTS + ("tests/test_merge_integrity.py",),
           "a folder holding one file of the user's is taken as empty"),
    # ------------------------------------------------------------------ runner: resume
    Mutant("resume-from-zero", RN, "start = (ckpts.latest_step() or 0) if run.resume else 0",
           "start = 0", RESUME_TESTS, "--resume starts the run again"),
    Mutant("resume-no-truncate", RN, "truncate = run.resume and run.primary",
           "truncate = False", RESUME_TESTS,
           "rows written after the last checkpoint stay twice in metrics.jsonl"),
    Mutant("resume-config-only", RN, 'if old.get("fingerprint") != spec["fingerprint"]:',
           'if old.get("config") != spec.get("config"):', RESUME_TESTS,
           "--resume with other --seeds or sweep continues the old run"),
    Mutant("resume-checkpoint-cadence", RN, "(chunk + 1) % every == 0",
           "chunk % every == 0", RESUME_TESTS, "checkpoints one chunk early"),
    Mutant("resume-keeps-wall-time-only", RN,
           "how.update({k: recorded[k] for k in HOW_RAN if k in recorded})",
           'how.update({k: recorded[k] for k in ("wall_time_s",) if k in recorded})',
           RESUME_TESTS, "--resume of a finished run rewrites resumed_from_step"),
    # ------------------------------------------------------------------ statistics
    Mutant("stats-ddof", ST, "x.std(axis=axis, ddof=1)", "x.std(axis=axis, ddof=0)",
           STATS_TESTS, "intervals too narrow"),
    Mutant("stats-welch-dof", ST, "vb**2 / (b.size - 1)", "vb**2 / b.size", STATS_TESTS,
           "Welch's degrees of freedom off"),
    Mutant("stats-resolve-n", ST, "max(n + 1, ", "max(n, ", STATS_TESTS,
           "asks for the seeds it already has"),
    Mutant("stats-running-mean-window", ST, "lo = np.maximum(n - int(window), 0)",
           "lo = np.maximum(n - int(window) - 1, 0)", STATS_TESTS,
           "windows one point too long"),
    Mutant("stats-crossing-strict", ST, "hit = running_mean(values, window, axis=0) >= level",
           "hit = running_mean(values, window, axis=0) > level", STATS_TESTS,
           "a curve that reaches the level exactly never crosses it"),
    Mutant("stats-change-states-at-change", ST, "for t in (c - 1, c + window, end - 1)]",
           "for t in (c, c + window, end - 1)]", STATS_TESTS,
           "states 'before' a change read after it"),
    Mutant("stats-t-table-edge", ST, "if df < len(_T975) + 1:", "if df <= len(_T975) + 1:",
           STATS_TESTS, "31 degrees of freedom index past the table"),
    Mutant("stats-welch-constant", ST, "    if va + vb == 0:\n        return diff, 0.0",
           '    if va + vb == 0:\n        return diff, float("nan")', STATS_TESTS,
           "two constant arms get no interval"),
    # ------------------------------------------------------------------ env base
    Mutant("env-reset-unchecked", EB,
           "        if not is_traced(params):\n            self.validate(params)\n"
           "        _, words, pixel",
           "        _, words, pixel", ENV_TESTS, "reset takes bad parameters outside jit"),
    Mutant("env-obs-of-old-state", EB,
           "return self.get_obs(nstate, params, eps), nstate, reward",
           "return self.get_obs(state, params, eps), nstate, reward", ENV_TESTS,
           "step's observation is of the state before the reset"),
    Mutant("env-layout-swapped", EB,
           "key, *blocks, (self.fresh_words if fresh else 0, fresh),\n"
           "            (self.pixel_noise_size(params), params.noise_on.pixel))",
           "key, *blocks, (self.pixel_noise_size(params), params.noise_on.pixel),\n"
           "            (self.fresh_words if fresh else 0, fresh))", ENV_TESTS,
           "fresh episodes drawn from the pixel noise's words"),
    Mutant("env-no-task-checks", EB,
           "validate(params)  # fields and every section's check() rule\n"
           "        self.check_params(params)",
           "validate(params)  # fields and every section's check() rule", ENV_TESTS,
           "a task's own consistency rules are skipped"),
]

BL, RD = "vbl/vision/blobs.py", "vbl/vision/render.py"
VISION_TESTS = ("tests/test_blobs.py", "tests/test_render_exact.py", "tests/test_pixel_bounds.py",
                "tests/test_pixel_obs.py")

#: Realistic bugs in the pixel pipeline (colour blobs, goal ends, the renderer's pixels).
VISION_MUTANTS = [
    Mutant("blobs-hue-mirrored", BL, "h = jnp.where(mx == r, (g - b) / safe,",
           "h = jnp.where(mx == r, (b - g) / safe,", VISION_TESTS,
           "hues next to red mirrored (orange reads as magenta)"),
    Mutant("blobs-dark-pixels-coloured", BL, "coloured = (s >= bp.sat_min) & (v >= bp.val_min)",
           "coloured = s >= bp.sat_min", VISION_TESTS, "dark pixels count as coloured"),
    Mutant("blobs-extent-from-centres", BL,
           "lo = jnp.min(jnp.where(any_px, centres, _BIG)) - 0.5 * size",
           "lo = jnp.min(jnp.where(any_px, centres, _BIG))", VISION_TESTS,
           "a blob's extent starts at its first pixel's centre, not its edge"),
    Mutant("blobs-centroid-unweighted", BL, "cu=jnp.sum(cols * u) * inv",
           "cu=jnp.sum((cols > 0) * u) / jnp.maximum(jnp.sum(cols > 0), 1.0)", VISION_TESTS,
           "the centroid averages columns, not pixels"),
    Mutant("blobs-row-factor-sign", BL, "return jnp.cos(tau) - (v / fv) * jnp.sin(tau)",
           "return jnp.cos(tau) + (v / fv) * jnp.sin(tau)", VISION_TESTS,
           "the post lines' slant for a tilted camera has the wrong sign"),
    Mutant("blobs-post-band-camera-px", BL, "band = mask & (dist <= bp.post_band * su)",
           "band = mask & (dist <= bp.post_band)", VISION_TESTS,
           "the post band in camera px: posts short at 128 x 120"),
    Mutant("blobs-clip-at-border", BL, "out = jnp.abs(u) > hw - 0.5 * su",
           "out = jnp.abs(u) > hw", VISION_TESTS,
           "a post leaving the image is not moved onto the border"),
    Mutant("render-rows-upside-down", RD,
           "v = (0.5 - (jnp.arange(height, dtype=F32) + 0.5) / height) * ch",
           "v = ((jnp.arange(height, dtype=F32) + 0.5) / height - 0.5) * ch", VISION_TESTS,
           "row 0 is the image's bottom"),
    Mutant("render-pixel-height-from-width", RD, "return u, v, (cw / width, ch / height)",
           "return u, v, (cw / width, cw / height)", VISION_TESTS,
           "a pixel's height taken from the image width"),
]

#: The mutants the check runs by default.
MUTANTS = ENGINE_MUTANTS + VISION_MUTANTS

SURVIVORS = ("tests/test_merge_integrity.py", "tests/test_engine_edge_cases.py")

#: The mutants issue 50 found surviving (``--issue``): the tests written for them kill them.
ISSUE_MUTANTS = [
    Mutant("issue-merge-last-part", M, "for i in range(1, n + 1) if i not in seen",
           "for i in range(1, n) if i not in seen", SURVIVORS,
           "the last missing part is never reported"),
    Mutant("issue-merge-no-realpath", M,
           "target = os.path.realpath(out)\n    for p in parts:\n"
           "        if os.path.realpath(p.folder) == target:",
           "target = out\n    for p in parts:\n        if p.folder == target:", SURVIVORS,
           "--out naming a shard by another path is not recognised"),
    Mutant("issue-folder-no-fingerprint", RF,
           'raise EngineError(f"{where} has no fingerprint; {fix}")', "return", SURVIVORS,
           "a config.json without a fingerprint is accepted"),
    Mutant("issue-folder-parent-allow-list", RF,
           "if str(parent) in _ALLOWED or not lock.is_file():", "if not lock.is_file():",
           SURVIVORS, "_check_parent ignores its allow list"),
    Mutant("issue-stats-bounded-threshold", ST, "x.size < MIN_SEEDS_BOUNDED",
           "x.size <= MIN_SEEDS_BOUNDED", SURVIVORS, "bounded_ci95's seed threshold"),
    Mutant("issue-stats-bounded-and", ST, "(m - h < lo or m + h > hi)",
           "(m - h < lo and m + h > hi)", SURVIVORS, "bounded_ci95's range test"),
    Mutant("issue-claim-larger-arm", "vbl/engine/report.py", "n = min(a.size, b.size)",
           "n = max(a.size, b.size)", SURVIVORS, "claim counts the larger arm's seeds"),
    Mutant("issue-mc-count-not-zeroed", "vbl/agents/monte_carlo.py",
           'sums.at[idx].set(\n            s * 0.0, mode="drop")', "sums", SURVIVORS,
           "a key's sums are not zeroed after its first write"),
    Mutant("issue-env-reset-on-terminated", EB, 'done = info["episode_done"]',
           "done = terminated", ENV_TESTS, "truncated episodes never reset"),
]


RP, CAM = "vbl/vision/render.py", "vbl/vision/camera.py"
CK, RS, RE = "vbl/engine/checkpoint.py", "vbl/engine/results.py", "vbl/engine/report.py"
EX, TU = "vbl/engine/export.py", "vbl/engine/tune.py"
RUNNER_TESTS = ("tests/test_engine_core.py", "tests/test_merge_integrity.py",
                "tests/test_shard_merge.py")
REPORT_TESTS = ("tests/test_engine_edge_cases.py", "tests/test_engine_core.py")
RENDER_TESTS = VISION_TESTS + ("tests/test_render.py",)
CAMERA_TESTS = ("tests/test_camera.py",) + RENDER_TESTS

#: A second, independent set of realistic bugs in the same modules (``--fresh``), written
#: from the code alone, before reading the tests: its score before any test was written for
#: it is the honest measure of the tests (``benchmarks/results/mutation_fresh.json``).
FRESH_MUTANTS = [
    # ------------------------------------------------------------------ statistics
    Mutant("stats-t-dof-n", ST, "t_quantile_975(n - 1) * x.std(axis=axis, ddof=1)",
           "t_quantile_975(n) * x.std(axis=axis, ddof=1)", STATS_TESTS,
           "the mean's interval takes n degrees of freedom, not n - 1: too narrow"),
    Mutant("stats-cornish-fisher-sign", ST,
           "return z + g1 / df + g2 / df**2 + g3 / df**3",
           "return z + g1 / df - g2 / df**2 + g3 / df**3", STATS_TESTS,
           "t quantiles beyond 30 degrees of freedom too small"),
    Mutant("stats-welch-var-ddof0", ST,
           "va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size",
           "va, vb = a.var() / a.size, b.var() / b.size", STATS_TESTS,
           "Welch's interval from population variances: too narrow"),
    Mutant("stats-resolve-rounds-down", ST,
           "math.ceil(n * (1.1 * half / abs(diff)) ** 2)",
           "int(n * (1.1 * half / abs(diff)) ** 2)", STATS_TESTS,
           "the seeds that would resolve a difference are rounded down"),
    Mutant("stats-last-change-ends-early", ST,
           "end = changes[i + 1] if i + 1 < len(changes) else n",
           "end = changes[i + 1] if i + 1 < len(changes) else n - 1", STATS_TESTS,
           "the last change's recovery ends one trial before the run does"),
    # ------------------------------------------------------------------ engine
    Mutant("merge-final-row-step", M,
           'keys += [(g.step_offset + g.num_chunks, "final", p, g.index)',
           'keys += [(g.step_offset + g.num_chunks + 1, "final", p, g.index)', MERGE_TESTS,
           "the merge expects a program's final rows one step late"),
    Mutant("merge-devices-max", M, '"devices": sum(num("devices"))',
           '"devices": max(num("devices"), default=0)', MERGE_TESTS,
           "the merged summary counts the largest shard's devices, not all"),
    Mutant("folder-marker-full-paths", RF, "{Path(n).name for n in names}",
           "{str(n) for n in names}", FOLDER_TESTS,
           "a file recorded by its path is never removed by --overwrite"),
    Mutant("runner-rows-first-point-seeds", RN,
           "seed_stats(np.asarray(v)[at:at + hi - lo])", "seed_stats(np.asarray(v)[lo:hi])",
           RUNNER_TESTS, "every sweep point's row holds the first point's seeds"),
    Mutant("runner-set-keeps-default-sweep", RN,
           "for p, v in experiment.sweep.items() if p not in fixed}",
           "for p, v in experiment.sweep.items()}", RUNNER_TESTS,
           "--set PATH=V of a default-swept path is swept over anyway"),
    Mutant("runner-empty-span", RN, "0 <= first < last <= n):",
           "0 <= first <= last <= n):", RUNNER_TESTS + ("tests/test_tune.py",),
           "a span of no chunks is accepted"),
    Mutant("checkpoint-leaf-names-unpadded", CK, 'out[f"leaf_{i:04d}"]',
           'out[f"leaf_{i}"]', RESUME_TESTS,
           "a carry of more than 10 leaves is restored in another order"),
    Mutant("results-truncate-drops-checkpoint-row", RS, 'if row["step"] <= step]',
           'if row["step"] < step]', RESUME_TESTS,
           "--resume drops the rows of the checkpointed chunk"),
    Mutant("report-claim-tie-is-yes", RE, "    if d - h > 0:", "    if d - h >= 0:",
           REPORT_TESTS, "two constant equal arms are claimed different"),
    Mutant("report-stat-cell-sqrt-n", RE, "sd / math.sqrt(n - 1)", "sd / math.sqrt(n)",
           REPORT_TESTS, "an interval from a population std is too narrow"),
    Mutant("tune-grid-misses-high", TU, "int(self.high) + 1))", "int(self.high)))",
           ("tests/test_tune.py",), "a grid over an int range leaves out its high end"),
    Mutant("export-shard-seeds-from-zero", EX,
           "seeds.append(np.arange(first, first + v.size))", "seeds.append(np.arange(v.size))",
           ("tests/test_export.py",), "a shard's seeds are numbered from 0 in its table"),
    # ------------------------------------------------------------------ vision
    Mutant("blobs-hue-not-circular", BL,
           "dh = jnp.abs(jnp.mod(h - hue + 180.0, 360.0) - 180.0)", "dh = jnp.abs(h - hue)",
           VISION_TESTS, "a red of hue 355 deg is not the ball's hue 4 deg"),
    Mutant("blobs-blue-hue-mirrored", BL, "4.0 + (r - g) / safe", "4.0 + (g - r) / safe",
           VISION_TESTS, "blue hues mirrored about 240 deg: the goal (228) reads 252"),
    Mutant("blobs-area-image-pixels", BL, "area=n * su * sv", "area=n", VISION_TESTS,
           "a blob's area counts image pixels, not camera px^2"),
    Mutant("blobs-min-post-camera-px", BL, "(b_hi - b_lo >= bp.min_post * sv)",
           "(b_hi - b_lo >= bp.min_post)", VISION_TESTS,
           "min_post taken in camera px, not image pixels"),
    Mutant("blobs-sec3-corner-order", BL,
           "gpts = jnp.stack([bot[0], top[0], top[1], bot[1]])",
           "gpts = jnp.stack([bot[0], top[0], bot[1], top[1]])", VISION_TESTS,
           "Section 3's goal corners out of their order"),
    Mutant("blobs-x5-sign", BL, "x5 = jnp.clip((hgt[0] - hgt[1])",
           "x5 = jnp.clip((hgt[1] - hgt[0])", VISION_TESTS,
           "the goal's perspective feature x5 has the wrong sign"),
    Mutant("render-ball-far-root", RP,
           "lam = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / a",
           "lam = (-b + jnp.sqrt(jnp.maximum(disc, 0.0))) / a", RENDER_TESTS,
           "rays hit the ball's far side"),
    Mutant("render-goal-bias-sign", RP, "jnp.where(hit, lam - GOAL_DEPTH_BIAS, _FAR)",
           "jnp.where(hit, lam + GOAL_DEPTH_BIAS, _FAR)", RENDER_TESTS,
           "the wall, not the goal, wins their tie: no goal pixels"),
    Mutant("render-uint8-truncates", RP,
           "return jnp.round(jnp.clip(img, 0.0, 1.0) * 255.0).astype(jnp.uint8)",
           "return (jnp.clip(img, 0.0, 1.0) * 255.0).astype(jnp.uint8)", RENDER_TESTS,
           "to_uint8 truncates instead of rounding"),
    Mutant("render-top-upside-down", RP,
           "y = ((0.5 * th - jnp.arange(th, dtype=F32) - 0.5) * scale)[:, None]",
           "y = ((jnp.arange(th, dtype=F32) + 0.5 - 0.5 * th) * scale)[:, None]",
           RENDER_TESTS, "the top view's +y points down"),
    Mutant("camera-fv-from-hfov", CAM, "jnp.asarray(cam.vfov_deg, F32)",
           "jnp.asarray(cam.hfov_deg, F32)", CAMERA_TESTS,
           "the vertical focal length from the horizontal field of view"),
    Mutant("camera-no-near-clamp", CAM,
           "zs = jnp.maximum(z, jnp.asarray(cam.near_plane, F32))", "zs = z", CAMERA_TESTS,
           "points behind the camera project to inf / flipped pixels"),
    Mutant("camera-offset-sideways", CAM, "c = jnp.stack([x + off * ct, y + off * st,",
           "c = jnp.stack([x + off * st, y + off * ct,", CAMERA_TESTS,
           "the camera's forward offset along the wrong axis"),
    # ------------------------------------------------------------------ env base
    Mutant("env-image-shape-swapped", EB, "return (rp.height, rp.width, 3)",
           "return (rp.width, rp.height, 3)", ENV_TESTS,
           "image_shape gives (W, H, 3) for a non-square image"),
    Mutant("env-ball-shape-unchecked", EB, "if robots != (n, 3) or ball != (2,):",
           "if robots != (n, 3):", ENV_TESTS, "a state with a batch of balls passes the check"),
    Mutant("env-autoreset-swapped", EB, "jnp.where(done, a, b), fresh, nstate)",
           "jnp.where(done, a, b), nstate, fresh)", ENV_TESTS,
           "step resets episodes that go on and continues those that ended"),
    Mutant("env-constructor-unvalidated", EB,
           "self._default_params = self.validate(self.defaults() if params is None else params)",
           "self._default_params = self.defaults() if params is None else params", ENV_TESTS,
           "the constructor takes bad default parameters"),
    Mutant("env-reset-ignores-params", EB,
           "        params = self._default_params if params is None else params\n"
           "        state, eps = self.reset_state(key, params)",
           "        params = self._default_params\n"
           "        state, eps = self.reset_state(key, params)", ENV_TESTS,
           "reset ignores the parameters it is given"),
]


TR, S2, S3 = "vbl/engine/tune_report.py", "vbl/vision/section2.py", "vbl/vision/section3.py"
TUNE_TESTS = ("tests/test_tune.py",)
FEATURE_TESTS = ("tests/test_features.py", "tests/test_vision_regions.py", "tests/test_camera.py")

#: A third set (``--blind``), written like ``--fresh`` from the code alone before any test
#: was read, in parts of the modules neither other set touched; its score before and after
#: the tests written for its survivors is in ``benchmarks/results/mutation_fresh.json``.
BLIND_MUTANTS = [
    # ------------------------------------------------------------------ engine
    Mutant("report-table-width-off-by-one", RE, "        if used + 3 + w > width:",
           "        if used + 3 + w >= width:", REPORT_TESTS + ("tests/test_engine_cli.py",),
           "a metric that fits the table's width exactly is left out"),
    Mutant("report-seeds-cell-one-bound", RE,
           "if bounds is None or bounds[0] <= m - half and m + half <= bounds[1]:",
           "if bounds is None or m + half <= bounds[1]:", REPORT_TESTS,
           "a rate's interval crossing 0 is printed as mean ± half-width below 0"),
    Mutant("report-claim-paired-ignored", RE,
           "d, h = mean_ci95(a - b) if paired else welch_ci95(a, b)",
           "d, h = welch_ci95(a, b)", REPORT_TESTS,
           "claim(paired=True) ignores the pairing (Welch's interval instead)"),
    Mutant("report-headline-prefers-last-chunk", RE,
           '    st = entry.get("final", {}).get(name)\n'
           '    return st if st is not None else entry.get("last_chunk", {}).get(name)',
           '    st = entry.get("last_chunk", {}).get(name)\n'
           '    return st if st is not None else entry.get("final", {}).get(name)',
           REPORT_TESTS + ("tests/test_engine_cli.py",),
           "the headline shows the last chunk's value of a metric that has a final one"),
    Mutant("export-last-chunk-is-first", EX,
           'r["chunk"] >= last[r["point"]]["chunk"]', 'r["chunk"] <= last[r["point"]]["chunk"]',
           ("tests/test_export.py",), "the final table's last_chunk rows are the first chunk's"),
    Mutant("tune-rungs-empty-last", TU, "    while r < num_chunks:", "    while r <= num_chunks:",
           TUNE_TESTS, "a rung boundary at the last chunk adds an empty rung"),
    Mutant("tune-rung-no-min-one", TU,
           'n_keep = max(1, len(competing) // s.spec["reduction_factor"])',
           'n_keep = len(competing) // s.spec["reduction_factor"]', TUNE_TESTS,
           "a rung of fewer trials than eta keeps them all, not the best one"),
    Mutant("tune-rung-minimize-off-by-one", TU, "else competing[n_keep - 1])",
           "else competing[n_keep])", TUNE_TESTS,
           "minimizing, a rung keeps one trial more than 1/eta"),
    Mutant("tune-objective-first-chunk", TU, "return a[logged[-1]] if len(logged) else a[-1]",
           "return a[logged[0]] if len(logged) else a[-1]", TUNE_TESTS,
           "a trial is scored on its first chunk, not its last"),
    Mutant("tune-log-range-from-zero", TU, 'if flag == "log" and lo <= 0:',
           'if flag == "log" and lo < 0:', TUNE_TESTS, "a :log range from 0 is accepted"),
    Mutant("tune-report-confirm-seed", TR,
           '"--seeds", str(s.spec["confirm_seeds"]), "--seed", str(s.spec["seed"] + 1)]',
           '"--seeds", str(s.spec["confirm_seeds"]), "--seed", str(s.spec["seed"])]',
           TUNE_TESTS, "the printed confirmation command reruns the search's seeds"),
    Mutant("folder-differing-one-sided", RF, "if (k in fa or k in fb) and not same(k)]",
           "if (k in fa and k in fb) and not same(k)]", FOLDER_TESTS,
           "a top-level field only one config.json has is not named as differing"),
    # ------------------------------------------------------------------ statistics
    Mutant("stats-running-mean-window-zero", ST, "    if int(window) < 1:",
           "    if int(window) < 0:", STATS_TESTS, "running_mean takes window 0 (NaN curve)"),
    Mutant("stats-crossing-shapes-unchecked", ST,
           "if values.shape != clock.shape or values.ndim != 2:", "if values.ndim != 2:",
           STATS_TESTS, "first_crossing takes a clock of another shape"),
    Mutant("stats-crossing-never-is-first-row", ST,
           "return np.where(hit.any(axis=0), clock[first, np.arange(clock.shape[1])], np.nan)",
           "return clock[first, np.arange(clock.shape[1])]", STATS_TESTS,
           "a seed that never crosses the level crosses at the first row"),
    Mutant("stats-bounded-lower-unclipped", ST, "return m, max(m - h, lo), min(m + h, hi)",
           "return m, m - h, min(m + h, hi)", STATS_TESTS,
           "bounded_ci95's lower end goes below the range"),
    Mutant("stats-mean-ci-n-axis0", ST, "    n = x.shape[axis]\n", "    n = x.shape[0]\n",
           STATS_TESTS, "mean_ci95 over axis 1 counts the rows as seeds"),
    # ------------------------------------------------------------------ vision
    Mutant("blobs-green-hue-mirrored", BL, "2.0 + (b - r) / safe", "2.0 + (r - b) / safe",
           VISION_TESTS, "hues between yellow and cyan mirrored about 120 deg"),
    Mutant("blobs-saturation-chroma", BL,
           "s = jnp.where(mx > 0, delta / jnp.where(mx > 0, mx, 1.0), 0.0)",
           "s = jnp.where(mx > 0, delta, 0.0)", VISION_TESTS,
           "saturation is the chroma: dark coloured pixels are not coloured"),
    Mutant("blobs-u-extent-row-size", BL, "u_lo, u_hi = _extent(cols > 0, u, su)",
           "u_lo, u_hi = _extent(cols > 0, u, sv)", VISION_TESTS,
           "a blob's u extent widened by a pixel's height, not its width"),
    Mutant("blobs-left-border-column-1", BL, "((-1.0, 0, -hw), (1.0, w - 1, hw))",
           "((-1.0, 1, -hw), (1.0, w - 1, hw))", VISION_TESTS,
           "a goal cut by the left border is read from the second column"),
    Mutant("blobs-sec2-lost-sides-swapped", BL,
           "jnp.where(bvis, 0.0, side[0]), jnp.where(gvis, 0.0, side[1])",
           "jnp.where(bvis, 0.0, side[1]), jnp.where(gvis, 0.0, side[0])", VISION_TESTS,
           "Section 2's lost sides of the ball and the goal swapped"),
    Mutant("render-halfway-line-axis", RP, "line = (jnp.abs(x) <= hw) | circ",
           "line = (jnp.abs(y) <= hw) | circ", RENDER_TESTS,
           "the halfway line drawn along the field's length"),
    Mutant("render-goal-no-top", RP,
           "(a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)", "(a >= 0) & (a <= 1) & (b >= 0)",
           RENDER_TESTS, "the goal mouth has no crossbar: the wall above it is blue"),
    Mutant("render-box-sunk", RP, "rel = [c[0] - pose[0], c[1] - pose[1], c[2] - half[2]]",
           "rel = [c[0] - pose[0], c[1] - pose[1], c[2]]", RENDER_TESTS,
           "the other robot's box is half sunk into the floor"),
    Mutant("render-world-other-radius", RP, "dia = 2 * jnp.asarray(world.robot.radius, F32)",
           "dia = jnp.asarray(world.robot.radius, F32)", RENDER_TESTS,
           "render_world draws the other robot half its size"),
    Mutant("camera-near-plane-equal-height", CAM, "if self.near_plane >= self.height:",
           "if self.near_plane > self.height:", CAMERA_TESTS,
           "a near plane at the camera's height passes the check"),
    Mutant("sec2-goal-lost-side-from-v", S2, "jnp.where(gvis, 0.0, lost_side(gcen[0]))",
           "jnp.where(gvis, 0.0, lost_side(gcen[1]))", FEATURE_TESTS,
           "a lost goal's side read from its height, not its side"),
    Mutant("sec2-check-zero-radius", S2, "not np.all(rad > 0)", "not np.all(rad >= 0)",
           FEATURE_TESTS, "check_inputs takes a ball of radius 0"),
    Mutant("sec3-robot-area-ignores-ball", S3, "o_area = jnp.maximum(o_in - o_occ, 0.0)",
           "o_area = jnp.maximum(o_in, 0.0)", FEATURE_TESTS,
           "the other robot's area keeps the part the ball hides"),
    # ------------------------------------------------------------------ env base
    Mutant("env-option-unchecked", EB, "        if choice not in self.choices:",
           "        if not choice:", ENV_TESTS, "the constructor takes an unknown option"),
    Mutant("env-image-shape-ignores-params", EB,
           "rp = (self._default_params if params is None else params).pixels.render",
           "rp = self._default_params.pixels.render", ENV_TESTS,
           "image_shape gives the default image's shape for other parameters"),
    Mutant("env-pixel-noise-per-pixel", EB, "return int(np.prod(self.image_shape(params)))",
           "return int(np.prod(self.image_shape(params)[:2]))", ENV_TESTS,
           "pixel noise draws one normal per pixel, not per colour channel"),
    Mutant("env-step-env-unchecked", EB,
           "        self._check_inputs(state, action, params)\n"
           "        eps, _, pixel = self._draw(key, params, transition=True, fresh=False)",
           "        eps, _, pixel = self._draw(key, params, transition=True, fresh=False)",
           ENV_TESTS, "step_env takes a bad action, state or parameters outside jit"),
    Mutant("env-validate-type-unchecked", EB,
           "        if not isinstance(params, self.params_type):",
           "        if params is None:", ENV_TESTS,
           "another task's parameters pass validation"),
]


SW, CF, PL = "vbl/engine/sweep.py", "vbl/engine/config.py", "vbl/engine/plots.py"
PG, MEM, REG = "vbl/engine/progress.py", "vbl/engine/memory.py", "vbl/engine/registry.py"
PD, PJ = "vbl/engine/paramdoc.py", "vbl/vision/projection.py"
PLOT_TESTS = ("tests/test_plots_and_progress.py",)
CLI_TESTS = ("tests/test_engine_cli.py", "tests/test_cli_first_use.py")
DOC_TESTS = ("tests/test_docs.py", "tests/test_params_page.py")
LENS_TESTS = ("tests/test_camera.py", "tests/test_features.py", "tests/test_render_exact.py")
PIXEL_ENV_TESTS = ENV_TESTS + ("tests/test_pixel_obs.py", "tests/test_brax_adapter.py")
PROJECTION_TESTS = ("tests/test_projection.py",) + FEATURE_TESTS

#: A fourth set (``--fourth``), written like ``--fresh`` and ``--blind`` from the source alone,
#: before any test was read or run against it, mostly in functions and files the other sets
#: leave alone (sweep plans, config parsing, plots, progress, memory, the registry, the docs
#: tables, the camera, the projection and the env base). A mutant runs the test files named
#: after its module first (test_checkpoint.py for checkpoint.py, and so on).
FOURTH_MUTANTS = [
    # ------------------------------------------------------------------ engine
    Mutant("sweep-shard-one-learner-each", SW,
           "if shard is not None and shard.count > total:",
           "if shard is not None and shard.count >= total:",
           ("tests/test_sweep_plan.py", "tests/test_shard_merge.py",
            "tests/test_sweep_scaling.py"),
           "--shard into as many parts as learners (one learner each) is refused"),
    Mutant("config-stack-seed-major", CF, "stacked.append(np.repeat(col, repeats, axis=0))",
           "stacked.append(np.tile(col, (repeats,) + (1,) * (col.ndim - 1)))",
           ("tests/test_config.py", "tests/test_engine_core.py", "tests/test_params.py"),
           "learner i gets the config of point i % points, not i // seeds"),
    Mutant("config-scalar-float-first", CF, "    for conv in (int, float):",
           "    for conv in (float, int):",
           ("tests/test_config.py", "tests/test_params.py", "tests/test_engine_cli.py"),
           "--set PATH=3 parses as the float 3.0: an int parameter refuses it"),
    Mutant("results-std-population", RS,
           "std = v.std(axis=0, ddof=1) if v.shape[0] > 1 else np.zeros_like(mean)",
           "std = v.std(axis=0) if v.shape[0] > 1 else np.zeros_like(mean)",
           ("tests/test_results.py",) + REPORT_TESTS,
           "summary.json's std over seeds is the population std (ddof 0)"),
    Mutant("plots-rate-needs-both-words", PL,
           'return "rate" in metric or "success" in metric',
           'return "rate" in metric and "success" in metric',
           PLOT_TESTS + ("tests/test_export.py",),
           "a metric named success (or *_rate) is not kept in [0, 1]"),
    Mutant("progress-eta-minutes-unit", PG,
           'return f"{seconds / 60:.0f} min" if seconds >= 90',
           'return f"{seconds:.0f} min" if seconds >= 90', PLOT_TESTS,
           "an ETA of 300 s shows as 300 min"),
    Mutant("memory-cgroup-limit-ignored", MEM, "return min(avail, cg) if cg is not None else avail",
           "return max(avail, cg) if cg is not None else avail",
           ("tests/test_engine_edge_cases.py", "tests/test_guards.py"),
           "a container's memory limit is ignored: a run too large for it passes the check"),
    Mutant("registry-script-needs-folder", REG,
           'return text.endswith(".py") or os.sep in text',
           'return text.endswith(".py") and os.sep in text', CLI_TESTS,
           "vbl run script.py (no folder in the path) looks for an experiment of that name"),
    Mutant("paramdoc-prefix-matches-longer-name", PD,
           "any(path == p or path.startswith(p + \".\") for p in prefixes)",
           "any(path.startswith(p) for p in prefixes)", DOC_TESTS,
           "a docs table of prefix noise also lists the noise_on rows"),
    Mutant("checkpoint-fallback-same-step", CK,
           "earlier = [s for s in self._mngr.all_steps() if s < step]",
           "earlier = [s for s in self._mngr.all_steps() if s <= step]",
           ("tests/test_checkpoint.py",) + RESUME_TESTS,
           "a corrupt checkpoint's error advises resuming from that same checkpoint"),
    Mutant("export-first-chunk-final", EX, 'cols["final"] = cols["chunk"] < 0',
           'cols["final"] = cols["chunk"] <= 0', ("tests/test_export.py",),
           "the first chunk's rows are marked final (their chunk <NA>)"),
    Mutant("tune-sampler-seed-per-search", TU,
           'seed = (s.spec["seed"] * 1_000_003 + k) % 2**32',
           'seed = (s.spec["seed"] * 1_000_003) % 2**32', TUNE_TESTS,
           "every batch's sampler has one seed: the random sampler asks batch 0's trials again"),
    Mutant("tune-last-batch-overshoots", TU, 'for _ in range(min(left, s.spec["batch"])):',
           'for _ in range(s.spec["batch"]):', TUNE_TESTS,
           "the last batch asks a full batch: more trials than --trials"),
    Mutant("tune-report-saved-is-used", TR, '"saved": 1.0 - ran / full if full else 0.0',
           '"saved": ran / full if full else 0.0', TUNE_TESTS,
           "the report's '% saved' is the share of the full grid's compute used"),
    # ------------------------------------------------------------------ statistics
    Mutant("stats-t-df-rounded-to-nearest", ST, "return _T975[int(df) - 1]",
           "return _T975[round(df) - 1]", STATS_TESTS,
           "Welch's fractional degrees of freedom rounded up: intervals too narrow"),
    Mutant("stats-welch-diff-reversed", ST, "diff = float(a.mean() - b.mean())",
           "diff = float(b.mean() - a.mean())", STATS_TESTS,
           "welch_ci95 gives mean(b) - mean(a): claims point the wrong way"),
    Mutant("stats-running-mean-full-divisor", ST, "(c[..., n] - c[..., lo]) / (n - lo)",
           "(c[..., n] - c[..., lo]) / int(window)", STATS_TESTS,
           "the first window - 1 points are divided by the full window: the curve starts low"),
    Mutant("stats-change-rates-over-seeds", ST, "success[:, max(a, 0):min(b, n)].mean(axis=1)",
           "success[:, max(a, 0):min(b, n)].mean(axis=0)", STATS_TESTS,
           "the rates around a change are averaged over seeds, not over the window's trials"),
    # ------------------------------------------------------------------ vision
    Mutant("camera-fu-from-height", CAM,
           "fu = jnp.asarray(cam.image_width, F32) / 2",
           "fu = jnp.asarray(cam.image_height, F32) / 2", LENS_TESTS,
           "the horizontal focal length from the image height"),
    Mutant("camera-up-axis-sign", CAM, "jnp.stack([-ct * sa, -st * sa, ca])",
           "jnp.stack([ct * sa, st * sa, ca])", LENS_TESTS,
           "a tilted camera's up axis leans the wrong way: v wrong off the image centre"),
    Mutant("projection-covered-end-negative", PJ, "    nhi = jnp.maximum(nhi, nlo)\n", "",
           PROJECTION_TESTS, "subtract_interval of an occluder covering it all gives hi < lo"),
    Mutant("projection-goal-end-upside-down", PJ, "a_low = q0v[k] <= q1v[k]",
           "a_low = q0v[k] >= q1v[k]", PROJECTION_TESTS,
           "a post's lower and upper ends swapped: a goal in view is lost"),
    Mutant("projection-ball-half-height-fu", PJ,
           "hs = jnp.asarray(cam.image_height, F32) / 2 / fv",
           "hs = jnp.asarray(cam.image_height, F32) / 2 / fu", PROJECTION_TESTS,
           "the ball's image is cut at the wrong rows: its v extent leaves the image"),
    Mutant("sec2-occluded-from-far-side", S2,
           "plane_side(corners, frame.c) > 0) & bi.valid",
           "plane_side(corners, frame.c) < 0) & bi.valid", FEATURE_TESTS,
           "a ball behind the goal hides it, a ball in front of it does not"),
    Mutant("sec2-goal-u-noise-reuses-h", S2,
           "u_end = u_end + jnp.where(ends.visible, std * eps[4:6], zero)",
           "u_end = u_end + jnp.where(ends.visible, std * eps[2:4], zero)", FEATURE_TESTS,
           "the goal ends' u noise reuses their height noise (eps[4:6] unused)"),
    # ------------------------------------------------------------------ env base
    Mutant("env-reset-obs-noise-free", EB,
           "        return self.get_obs(state, params, eps), state",
           "        return self.get_obs(state, params), state", ENV_TESTS,
           "reset's observation has no pixel noise"),
    Mutant("env-last-action-refused", EB,
           "check_action_index(action, self.num_actions, self.name",
           "check_action_index(action, self.num_actions - 1, self.name", ENV_TESTS,
           "the last action primitive is refused as out of range"),
    Mutant("env-image-noise-any-source", EB,
           'img_eps = None if eps is None or params.obs_source != "pixels" else',
           "img_eps = None if eps is None else", PIXEL_ENV_TESTS,
           "get_pixels takes the analytic features' noise for image noise (fails)"),
]


SS, SH, NS = "vbl/engine/seed_subsets.py", "vbl/engine/sharding.py", "vbl/engine/nested.py"
ER, RB, TB = "vbl/engine/errors.py", "vbl/engine/rebuild.py", "vbl/engine/tensorboard.py"
PR, SC = "vbl/engine/process.py", "vbl/vision/scenes.py"
SEED_SUBSET_TESTS = ("tests/test_seed_subsets.py", "tests/test_report.py")
ERROR_TESTS = ("tests/test_errors.py", "tests/test_cli_processes.py",
               "tests/test_engine_edge_cases.py", "tests/test_guards.py")
REBUILD_TESTS = ("tests/test_rebuild.py", "tests/test_report.py", "tests/test_reproduce_plan.py")
REGION_TESTS = ("tests/test_vision_regions.py", "tests/test_features.py",
                "tests/test_segmentation_parts.py")

#: A fifth set (``--fifth``), written from the source alone without reading any test, in
#: lines the other sets leave alone (seed subsets, learner batches, nested programs, error
#: lines, rebuilt commands, TensorBoard steps, the camera, the projection, Section 3 and the
#: env base). A mutant runs the test file named after its module first, where there is one.
FIFTH_MUTANTS = [
    # ------------------------------------------------------------------ engine
    Mutant("subsets-all-seeds-refused", SS, "not 1 <= seeds <= res.seeds:",
           "not 1 <= seeds < res.seeds:", SEED_SUBSET_TESTS,
           "vbl report --seeds K with K = the run's seeds is refused"),
    Mutant("subsets-curves-cut-chunks", SS, "curves = {k: a[:, :, :seeds]",
           "curves = {k: a[:, :seeds]", SEED_SUBSET_TESTS,
           "the rebuilt curves keep the first K chunks of every seed, not the first K seeds"),
    Mutant("sharding-batches-floor", SH, "nb = math.ceil(num_learners / cap)",
           "nb = max(1, num_learners // cap)",
           ("tests/test_sweep_scaling.py", "tests/test_per_device_programs.py",
            "tests/test_engine_core.py"),
           "learners are split into too few batches: a batch exceeds --learner-batch"),
    Mutant("nested-skips-first-chunk", NS, "jax.lax.fori_loop(0, chunks + prog.final_steps",
           "jax.lax.fori_loop(1, chunks + prog.final_steps",
           ("tests/test_segmentation_parts.py", "tests/test_final_through_step.py"),
           "a nested program runs one chunk fewer than it has, and its totals miss one"),
    Mutant("errors-file-too-large-not-disk", ER,
           "_DISK = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)",
           "_DISK = (errno.ENOSPC, errno.EDQUOT)", ERROR_TESTS,
           "a file size limit (EFBIG) is an unexpected error, not 'free some space, --resume'"),
    Mutant("errors-debug-false-is-on", ER,
           'return os.environ.get("VBL_DEBUG", "").strip().lower() not in ("", "0", "false", "no")',
           'return os.environ.get("VBL_DEBUG", "").strip().lower() not in ("", "0")',
           ERROR_TESTS, "VBL_DEBUG=false (or no) turns debugging on"),
    Mutant("errors-read-only-fs-unexplained", ER,
           "x.errno in (errno.EACCES, errno.EPERM, errno.EROFS)",
           "x.errno in (errno.EACCES, errno.EPERM)", ERROR_TESTS,
           "a read-only file system is an unexpected error, not 'make the folder writable'"),
    Mutant("rebuild-one-item-tuple-bare", RB, "numeric and len(items) > 1 else",
           "numeric else", REBUILD_TESTS,
           "a recorded one-number tuple is written --set k=0.5, which parses as a scalar"),
    Mutant("rebuild-quick-seeds-ignored", RB,
           "if seeds != ((exp.quick_seeds or exp.seeds) if quick else exp.seeds):",
           "if seeds != exp.seeds:", REBUILD_TESTS,
           "a --quick run's command adds --seeds for the quick default, or drops a needed one"),
    Mutant("tensorboard-step-zero-based", TB, 'else r["chunk"] + 1',
           'else r["chunk"]', ("tests/test_tensorboard.py",),
           "TensorBoard scalars are logged at chunk index, one step before the chunks done"),
    Mutant("checkpoint-keeps-one", CK, "max_to_keep: int = 2", "max_to_keep: int = 1",
           ("tests/test_checkpoint.py",) + RESUME_TESTS,
           "only the last checkpoint is kept: a corrupt one has no earlier one to resume from"),
    Mutant("process-host-devices-max-refused", PR, "if not 1 <= n <= most:",
           "if not 1 <= n < most:",
           ("tests/test_cli_processes.py", "tests/test_per_device_programs.py"),
           "VBL_HOST_DEVICES at its documented maximum (4 x cores) is refused"),
    # ------------------------------------------------------------------ stats
    Mutant("stats-resolve-negative-diff", ST, "abs(diff) > ZERO_DIFFERENCE_RTOL * half",
           "diff > ZERO_DIFFERENCE_RTOL * half", STATS_TESTS,
           "seeds_to_resolve gives None for every negative difference"),
    Mutant("stats-running-mean-axis-ignored", ST,
           "x = np.moveaxis(np.asarray(x, np.float64), axis, -1)",
           "x = np.asarray(x, np.float64)", STATS_TESTS,
           "running_mean averages along the last axis whatever axis is given"),
    Mutant("stats-bounded-one-seed-none", ST, "        return m, m, m\n",
           "        return None\n", STATS_TESTS,
           "bounded_ci95 of one seed says too few seeds instead of giving the mean"),
    Mutant("stats-change-after-skips-change", ST, "(c, c + window), (end - window, end)]",
           "(c + 1, c + window + 1), (end - window, end)]", STATS_TESTS,
           "the rate right after a change leaves out the change's own trial"),
    # ------------------------------------------------------------------ vision
    Mutant("sec2-goal-lost-side-world-frame", S2, "gcen = jnp.mean(pc, axis=0)",
           "gcen = jnp.mean(corners, axis=0)", FEATURE_TESTS,
           "a lost goal's side read from world coordinates, not the camera's"),
    Mutant("sec2-check-batch-ndim-only", S2, "if batch is not None and lead != batch:",
           "if batch is not None and len(lead) != len(batch):", FEATURE_TESTS,
           "check_inputs takes inputs of different batch sizes (same number of batch axes)"),
    Mutant("camera-tilt-degrees-as-radians", CAM,
           "tau = jnp.deg2rad(jnp.asarray(cam.tilt_deg, F32))",
           "tau = jnp.asarray(cam.tilt_deg, F32)", LENS_TESTS,
           "the camera's tilt in degrees is taken as radians"),
    Mutant("camera-depth-clamped", CAM, "return uv.astype(F32), z.astype(F32)",
           "return uv.astype(F32), zs.astype(F32)", LENS_TESTS,
           "project_points reports a point behind the camera at the near plane's depth"),
    Mutant("projection-clip-keeps-missed-segment", PJ, "    ok = ok & (t0 <= t1)\n", "",
           PROJECTION_TESTS,
           "a goal post wholly outside the image is clipped to a segment that counts as seen"),
    Mutant("projection-border-columns-swapped", PJ, "for k, col in ((0, -hw), (1, hw)):",
           "for k, col in ((0, hw), (1, -hw)):", PROJECTION_TESTS,
           "a post outside the image has its end on the opposite border column"),
    Mutant("projection-column-chord-fv", PJ, "_chord(u / fu, x, y, z, k)",
           "_chord(u / fv, x, y, z, k)", PROJECTION_TESTS,
           "the ball's column chord is read at u / fv: the goal end it hides is cut wrongly"),
    Mutant("scenes-left-right-swapped", SC, 'sgn = 1.0 if kind == "left" else -1.0',
           'sgn = 1.0 if kind == "right" else -1.0',
           ("tests/test_blobs.py", "tests/test_render.py"),
           "'left' scenes cut the ball by the right image border and 'right' ones by the left"),
    Mutant("sec3-hidden-ball-visible", S3, "ball_vis = bi.visible & jnp.all(uhi > ulo)",
           "ball_vis = bi.visible", REGION_TESTS,
           "a ball wholly hidden behind the other robot counts as visible"),
    Mutant("sec3-flatten-visible-lost-swapped", S3,
           "obs.visible,\n                            obs.lost_side]",
           "obs.lost_side,\n                            obs.visible]", REGION_TESTS,
           "flatten_section3 puts the lost sides before the visible flags"),
    # ------------------------------------------------------------------ env base
    Mutant("env-step-env-obs-noise-free", EB,
           "return self.get_obs(state, params, pixel), state, reward",
           "return self.get_obs(state, params), state, reward", ENV_TESTS,
           "step_env's observation has no pixel noise"),
    Mutant("env-step-env-ignores-params", EB,
           "        params = self._default_params if params is None else params\n"
           "        self._check_inputs(state, action, params)\n"
           "        eps, _, pixel",
           "        params = self._default_params\n"
           "        self._check_inputs(state, action, params)\n"
           "        eps, _, pixel", ENV_TESTS,
           "step_env ignores the parameters it is given"),
    Mutant("env-state-type-unchecked", EB,
           "        if not isinstance(state, self.state_type):",
           "        if state is None:", ENV_TESTS,
           "another task's state (or any object with a world) passes the input checks"),
    Mutant("env-image-noise-std-ignored", EB,
           "img_eps, observer.image_noise_std)", "img_eps, 0.0)", PIXEL_ENV_TESTS,
           "get_pixels draws image noise with std 0: pixel observations are noise-free"),
]


def _apply(text: str, m: Mutant) -> str:
    if text.count(m.old) != 1:
        raise ValueError(f"mutant {m.name}: its snippet occurs {text.count(m.old)} times in "
                         f"{m.file} (exactly once wanted); update the mutant")
    return text.replace(m.old, m.new)


def _copy_repo(dst: Path) -> None:
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".pytest_cache")
    for name in COPIED:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, dst / name, ignore=ignore, symlinks=True)
        elif src.exists():
            shutil.copy2(src, dst / name)


def _pytest(root: Path, tests: tuple[str, ...], timeout: float) -> tuple[str, float, str]:
    """Run ``tests`` in ``root``: ("pass" | "fail" | "timeout" | "error", seconds, the
    summary lines of pytest's output)."""
    env = dict(os.environ, PYTHONPATH=str(root), PYTHONDONTWRITEBYTECODE="1")
    cmd = [sys.executable, "-m", "pytest", "-n", "0", "-q", "-x", "-p", "no:cacheprovider",
           "--timeout", str(int(timeout)), *tests]
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True,
                           timeout=timeout + 30)
    except subprocess.TimeoutExpired:
        return "timeout", time.perf_counter() - t0, ""
    code = {0: "pass", 1: "fail"}.get(r.returncode, "error")
    if code == "fail" and "Timeout" in r.stdout[-5000:]:
        code = "timeout"
    said = "\n".join(x for x in r.stdout.splitlines()
                     if x.startswith(("FAILED", "ERROR")) or " passed" in x or " failed" in x)
    return code, time.perf_counter() - t0, said


def _check_copy_is_imported(root: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(root))
    out = subprocess.run([sys.executable, "-c", "import vbl; print(vbl.__file__)"], cwd=root,
                         env=env, capture_output=True, text=True).stdout.strip()
    if not out.startswith(str(root)):
        raise SystemExit(f"mutation_check: the copy's vbl is not the one imported ({out})")


def run(mutants: list[Mutant], timeout: float) -> list[dict]:
    """Baseline, then each mutant alone; one dict per mutant."""
    with tempfile.TemporaryDirectory(prefix="vbl-mutants-") as tmp:
        root = Path(tmp)
        _copy_repo(root)
        _check_copy_is_imported(root)
        originals = {m.file: (root / m.file).read_text() for m in mutants}
        for m in mutants:
            _apply(originals[m.file], m)  # every snippet found before anything runs
        for tests in sorted({m.tests for m in mutants}):
            status, secs, said = _pytest(root, tests, timeout)
            print(f"baseline {' '.join(tests)}: {status} ({secs:.0f} s)", flush=True)
            if status != "pass":
                raise SystemExit(f"mutation_check: the tests fail unmutated: {tests}\n{said}")
        results = []
        for m in mutants:
            path = root / m.file
            try:
                path.write_text(_apply(originals[m.file], m))
                status, secs, _ = _pytest(root, m.tests, timeout)
            finally:
                path.write_text(originals[m.file])
            verdict = "survived" if status == "pass" else "caught"
            results.append(dict(name=m.name, file=m.file, why=m.why, status=status,
                                verdict=verdict, seconds=round(secs, 1)))
            print(f"{verdict:8s} {m.name:34s} {status:7s} {secs:5.0f} s  {m.why}", flush=True)
    return results


#: Every set by the option that runs it (no option: the default set).
SETS = {"default": MUTANTS, "--issue": ISSUE_MUTANTS, "--fresh": FRESH_MUTANTS,
        "--blind": BLIND_MUTANTS, "--fourth": FOURTH_MUTANTS, "--fifth": FIFTH_MUTANTS}
ALL_MUTANTS = [m for ms in SETS.values() for m in ms]


def _set_of(m: Mutant) -> str:
    """The option that runs ``m``'s set: "default", "--issue", "--fresh", "--blind",
    "--fourth" or "--fifth"."""
    return next(k for k, ms in SETS.items() if m in ms)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", nargs="+", metavar="NAME", help="run these mutants only")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--issue", action="store_true",
                       help="the mutants issue 50 found surviving, instead of the default ones")
    which.add_argument("--fresh", action="store_true",
                       help="the second, independent set (FRESH_MUTANTS), instead of the "
                            "default ones")
    which.add_argument("--blind", action="store_true",
                       help="the third set (BLIND_MUTANTS), also written before reading the "
                            "tests, instead of the default ones")
    which.add_argument("--fourth", action="store_true",
                       help="the fourth set (FOURTH_MUTANTS), written from the source alone "
                            "before its tests were run")
    which.add_argument("--fifth", action="store_true",
                       help="the fifth set (FIFTH_MUTANTS), written from the source alone "
                            "before its tests were run")
    p.add_argument("--list", action="store_true", help="list the mutants and exit")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per test run")
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = p.parse_args(argv)
    named = [k for k in SETS if k != "default" and getattr(args, k[2:])]
    chosen = SETS[named[0] if named else "default"]
    if args.only:
        bad = [n for n in args.only if n not in {m.name for m in ALL_MUTANTS}]
        if bad:
            p.error(f"no mutant {', '.join(bad)}; --list shows them")
        chosen = [m for m in ALL_MUTANTS if m.name in args.only]
    if args.list:
        shown = chosen if args.only or named else ALL_MUTANTS
        for m in shown:
            print(f"{_set_of(m):7s} {m.name:38s} {m.file:26s} {m.why}")
        return 0
    try:
        results = run(chosen, args.timeout)
    except ValueError as e:
        print(f"mutation_check: {e}", file=sys.stderr)
        return 2
    caught = sum(r["verdict"] == "caught" for r in results)
    print(f"score: {caught}/{len(results)} caught"
          + (f" ({100 * caught / len(results):.0f} %)" if results else ""))
    survived = [r["name"] for r in results if r["verdict"] == "survived"]
    if survived:
        print("survived: " + ", ".join(survived))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")
    return 1 if survived else 0


if __name__ == "__main__":
    sys.exit(main())
