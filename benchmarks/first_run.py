"""A new user's first run: ``vbl reproduce --quick`` with an empty compilation cache (cold),
then the same command again (warm).

The cold run traces and compiles every program; the warm run reads them back (XLA's
persistent cache and vbl's trace cache, both in the same fresh cache folder), so what is
left is start-up and run time. Writes ``benchmarks/results/first_run.json`` and ``.md``:
per reproduce run, wall and CPU seconds (its worker process, all threads) cold and warm;
totals; whether each run's metrics.jsonl is byte-identical cold and warm; the machine and
its load average before and after each command.

Run: ``python benchmarks/first_run.py`` (two quick reproduces: about 10 minutes on a quiet
2-core machine). ``--only NAME`` limits it to some paper experiments; ``--quick`` to one.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.hardware import children_cpu_s, hardware_info, write_results  # noqa: E402

COLD_TARGET_S = 240.0  #: s wall, cold ``vbl reproduce --quick`` on a quiet 2-core machine
WARM_TARGET_S = 120.0  #: s wall, the same command again
QUICK_ONLY = "table1_identification"  #: the one experiment of ``--quick``
BEFORE = ROOT / "benchmarks" / "results" / "first_run_before.json"
"""This benchmark's result for the code before the quick run held the paper's rows only
(commit da16431: 8 runs, with the PPO comparators and Table 2's velocity control)."""


def reproduce_twice(work: pathlib.Path, only: list[str], env: dict[str, str]) -> dict:
    """Run ``vbl reproduce --quick`` cold and warm in ``work`` (its cache folder made
    empty first); returns each command's wall, CPU and load, and its manifest."""
    env = dict(env, VBL_JAX_CACHE=str(work / "cache"))
    out: dict = {}
    for phase in ("cold", "warm"):
        folder = work / phase
        cmd = [sys.executable, "-m", "vbl.cli", "reproduce", "--quick", "--quiet", "--out",
               str(folder)] + [a for name in only for a in ("--only", name)]
        load0, cpu0, t0 = os.getloadavg()[0], children_cpu_s(), time.perf_counter()
        proc = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"first_run: {' '.join(cmd[2:])} exited {proc.returncode}: "
                             f"{proc.stderr.strip().splitlines()[-1:]}")
        out[phase] = dict(wall_s=round(time.perf_counter() - t0, 1),
                          cpu_s=round(children_cpu_s() - cpu0, 1),
                          load_average=[load0, os.getloadavg()[0]],
                          manifest=json.loads((folder / "reproduce.json").read_text()))
    runs = [r["folder"] for r in out["cold"]["manifest"]["runs"]]
    out["metrics_equal"] = {f: (work / "cold" / f / "metrics.jsonl").read_bytes()
                            == (work / "warm" / f / "metrics.jsonl").read_bytes()
                            for f in runs}
    return out


def markdown(result: dict, before: dict | None = None) -> str:
    """The per-run table, the two commands' totals and, with ``before`` (this benchmark's
    JSON of earlier code), that code's totals: its commit and its runs."""
    hw, cold, warm = result["hardware"], result["cold"], result["warm"]
    warm_runs = {r["folder"]: r for r in warm["manifest"]["runs"]}
    lines = [f"First run ({hw['cpu']}, {hw['cores']} cores, jax {hw['jax']}; "
             f"`{result['command']}`): `vbl reproduce --quick` with an empty compilation "
             "cache (cold), then again (warm). Wall and CPU seconds per run (its worker "
             "process, all threads); `same`: its metrics.jsonl is byte-identical cold and "
             "warm.", "",
             "| run | cold: wall s | cold: CPU s | warm: wall s | warm: CPU s | same |",
             "|---|---:|---:|---:|---:|---|"]
    for r in cold["manifest"]["runs"]:
        w = warm_runs[r["folder"]]
        lines.append(f"| {r['folder']} | {r['seconds']:.0f} | {r['cpu_s']:.0f} | "
                     f"{w['seconds']:.0f} | {w['cpu_s']:.0f} | "
                     f"{'yes' if result['metrics_equal'][r['folder']] else '**no**'} |")
    for name, p, goal in (("cold", cold, COLD_TARGET_S), ("warm", warm, WARM_TARGET_S)):
        lines.append(f"| **{name} command** | **{p['wall_s']:.0f}** | **{p['cpu_s']:.0f}** | "
                     f"load {p['load_average'][0]:.1f} -> {p['load_average'][1]:.1f} | "
                     f"target <= {goal:.0f} s wall: "
                     f"{'met' if p['wall_s'] <= goal else 'not met'} | |")
    if before:
        runs = ", ".join(r["folder"] for r in before["cold"]["manifest"]["runs"])
        lines += ["", f"Before: commit `{before['cold']['manifest']['commit'][:7]}` on "
                  f"{before['hardware']['cpu']} ({runs}): cold "
                  f"{before['cold']['wall_s']:.0f} s wall / {before['cold']['cpu_s']:.0f} "
                  f"CPU s (load {before['cold']['load_average'][0]:.1f} at the start), warm "
                  f"{before['warm']['wall_s']:.0f} s wall / {before['warm']['cpu_s']:.0f} "
                  f"CPU s (`{BEFORE.relative_to(ROOT)}`)."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=[], metavar="NAME",
                    help="paper experiments to run (default: every one)")
    ap.add_argument("--quick", action="store_true",
                    help=f"only {QUICK_ONLY} (the shortest quick run; about a minute)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "first_run"))
    ap.add_argument("--keep", metavar="PATH",
                    help="copy the cold run's folder (a whole quick reproduce) to PATH, "
                         "which must not exist")
    args = ap.parse_args(argv)
    if args.keep and pathlib.Path(args.keep).exists():
        raise SystemExit(f"first_run: --keep {args.keep} exists; give a new folder")
    if args.quick:
        args.only = [QUICK_ONLY]
    with tempfile.TemporaryDirectory(prefix="vbl-first-run-") as work:
        result = dict(benchmark="first_run", hardware=hardware_info(),
                      command="python benchmarks/first_run.py" + "".join(
                          f" --only {n}" for n in args.only),
                      cold_target_s=COLD_TARGET_S, warm_target_s=WARM_TARGET_S,
                      **reproduce_twice(pathlib.Path(work), args.only, dict(os.environ)))
        if args.keep:
            shutil.copytree(pathlib.Path(work) / "cold", args.keep)
    before = json.loads(BEFORE.read_text()) if BEFORE.exists() and not args.only else None
    text = markdown(result, before)
    write_results(pathlib.Path(args.out), result, text)
    print(text)
    return result


if __name__ == "__main__":
    main()
