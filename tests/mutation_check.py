"""Mutation check: do the tests notice realistic bugs in the engine's run folders, merge and
resume, the statistics over seeds, the env base and the pixel pipeline (colour blobs, goal
ends, the renderer's pixels)?

Each mutant is one edit (a snippet of a file and what replaces it) that a person could
make by mistake. The check copies the repository's code and tests to a temporary folder,
runs each mutant's tests there once unmutated (they must pass), then applies each mutant
alone, runs its tests (stopping at the first failure, with a timeout) and restores the
file. A mutant is *caught* when its tests fail (or time out), *survived* when they pass.
The working tree is never touched, so other work in it goes on.

    .venv/bin/python tests/mutation_check.py                 # every mutant
    .venv/bin/python tests/mutation_check.py --only stats-ddof merge-unsorted
    .venv/bin/python tests/mutation_check.py --issue         # issue 50's survivors
    .venv/bin/python tests/mutation_check.py --list
    .venv/bin/python tests/mutation_check.py --json results.json

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
COPIED = ("vbl", "tests", "experiments", "docs", "pyproject.toml")


class Mutant(NamedTuple):
    name: str
    file: str            #: path in the repository
    old: str             #: snippet that occurs exactly once in ``file``
    new: str             #: what replaces it
    tests: tuple[str, ...]  #: pytest arguments (files or node ids)
    why: str             #: the behaviour it breaks


MERGE_TESTS = ("tests/test_merge_integrity.py", "tests/test_shard_merge.py")
FOLDER_TESTS = ("tests/test_reliability_survivors.py", "tests/test_run_folder_safety.py",
                "tests/test_cli_processes.py")
RESUME_TESTS = ("tests/test_merge_integrity.py", "tests/test_engine_core.py")
STATS_TESTS = ("tests/test_stats.py", "tests/test_reliability_survivors.py")
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

#: The fresh mutants the check runs by default.
MUTANTS = ENGINE_MUTANTS + VISION_MUTANTS

SURVIVORS = ("tests/test_merge_integrity.py", "tests/test_reliability_survivors.py")

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
           'sums.at[idx, 0].set(\n            0.0, mode="drop")', "sums", SURVIVORS,
           "a key's count is not zeroed after its first write"),
    Mutant("issue-env-reset-on-terminated", EB, 'done = info["episode_done"]',
           "done = terminated", ENV_TESTS, "truncated episodes never reset"),
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


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", nargs="+", metavar="NAME", help="run these mutants only")
    p.add_argument("--issue", action="store_true",
                   help="the mutants issue 50 found surviving, instead of the fresh ones")
    p.add_argument("--list", action="store_true", help="list the mutants and exit")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per test run")
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = p.parse_args(argv)
    chosen = ISSUE_MUTANTS if args.issue else MUTANTS
    if args.only:
        names = {m.name for m in MUTANTS + ISSUE_MUTANTS}
        bad = [n for n in args.only if n not in names]
        if bad:
            p.error(f"no mutant {', '.join(bad)}; --list shows them")
        chosen = [m for m in MUTANTS + ISSUE_MUTANTS if m.name in args.only]
    if args.list:
        for m in chosen:
            print(f"{m.name:34s} {m.file:22s} {m.why}")
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
