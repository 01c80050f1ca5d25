"""Probe: what the README's test command costs, with an empty compilation cache and again.

Runs ``python -m pytest`` (the README's second quick-start command; pytest's ``addopts``
leave out the ``slow`` tests) twice with ``VBL_JAX_CACHE`` in one fresh folder: cold (every
program traced and compiled) and warm (the programs read back from XLA's persistent
cache). Per phase: wall seconds, CPU seconds of pytest and its workers (all threads), and
the passed / failed counts of pytest's closing line; the machine and its load average
before and after each phase.

Not an experiment (``vbl reproduce`` does not run it) and not a benchmark (``vbl bench``
reads ``benchmarks/*.py`` only). Run from the repository root:

    python benchmarks/probes/suite_time.py [--out runs/suite_time] [--tiny]

Writes ``benchmarks/results/suite_time.json``: per invocation (key: the tests run, ``all``
for the whole suite) both phases, keeping the entries of other invocations. ``--tiny`` (a
smoke test: one small test file) checks that the probe runs and writes into ``--out``
only. Cost: the suite twice (tens of minutes on 2 cores). Cited by the README
("Development").
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from benchmarks.hardware import children_cpu_s, hardware_info, load_average, write_entry  # noqa: E402

RESULT = ROOT / "benchmarks" / "results" / "suite_time.json"
TINY_TESTS = "tests/test_stats.py"  #: the smoke test's one file (no compilation to speak of)
#: pytest's closing line: "N passed[, N failed][, ...] in S s"
CLOSING = re.compile(r"^=*\s*(.*\d+ (?:passed|failed).*) in [\d.]+s", re.M)


def counts(output: str) -> dict[str, int]:
    """``{"passed": N, "failed": N, ...}`` of pytest's closing line in ``output`` ({} if
    there is none)."""
    lines = CLOSING.findall(output)
    if not lines:
        return {}
    return {word: int(n) for n, word in re.findall(r"(\d+) (\w+)", lines[-1])}


def run_phase(tests: list[str], cache: Path) -> dict:
    """One ``python -m pytest [tests]`` with ``VBL_JAX_CACHE=cache``: wall, CPU, counts."""
    env = dict(os.environ, VBL_JAX_CACHE=str(cache))
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *tests]
    load0, cpu0, t0 = load_average(), children_cpu_s(), time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    found = counts(proc.stdout)
    if proc.returncode != 0 or not found.get("passed"):
        tail = (proc.stdout + proc.stderr).strip().splitlines()[-3:]
        raise SystemExit(f"suite_time: pytest exited {proc.returncode}: {tail}")
    loads = [None if x is None else round(x, 2) for x in (load0, load_average())]
    return dict(wall_s=round(wall, 1), cpu_s=round(children_cpu_s() - cpu0, 1),
                counts=found, load_average=loads)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/suite_time",
                    help="results folder of --tiny (default: runs/suite_time)")
    ap.add_argument("--tiny", action="store_true", help=f"smoke test: {TINY_TESTS} only")
    args = ap.parse_args(argv)
    tests = [TINY_TESTS] if args.tiny else []
    with tempfile.TemporaryDirectory(prefix="vbl-suite-cache-") as cache:
        phases = {phase: run_phase(tests, Path(cache)) for phase in ("cold", "warm")}
    hw = hardware_info()
    entry = dict(command=f"python benchmarks/probes/suite_time.py{' --tiny' if args.tiny else ''}",
                 cpu=hw["cpu"], cores=hw["cores"], jax=hw["jax"], **phases)
    dest = Path(args.out) / "suite_time.json" if args.tiny else RESULT
    write_entry(dest, " ".join(tests) or "all", entry)
    print("| phase | wall s | CPU s | passed | load average (before, after) |\n"
          "|---|---:|---:|---:|---|")
    for phase, r in phases.items():
        load = ", ".join(f"{x:.1f}" for x in r["load_average"] if x is not None)
        print(f"| {phase} | {r['wall_s']:.0f} | {r['cpu_s']:.0f} | {r['counts']['passed']} | "
              f"{load} |")
    print(f"{hw['cpu']}, {hw['cores']} cores; results in {dest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
