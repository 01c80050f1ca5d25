"""``vbl bench``: run the benchmark scripts of the source tree, results into a folder of the
user's choice, each headline figure beside its target with a verdict.

A benchmark is a script ``benchmarks/<name>.py`` with a ``__main__`` block (helper modules
such as ``hardware.py`` are not run). The scripts write their results to
``<source>/benchmarks/results/``; to keep the committed results as they are, every script
runs from a copy of the benchmark folder under ``OUT/.scripts/`` whose ``results`` is
``OUT`` itself (the rest of the source tree is linked, not copied). ``--out
benchmarks/results`` runs the scripts in place and updates the committed results.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vbl.engine.errors import EngineError
from vbl.engine.registry import source_folder
from vbl.params import ParamError

__all__ = ["DEFAULT_OUT", "Target", "TARGETS", "bench_dir", "benchmarks", "headline",
           "run_benchmarks"]

DEFAULT_OUT = "vbl-bench"  #: results folder of ``vbl bench`` (relative to the current folder)


def bench_dir() -> Path:
    """The benchmark folder: ``$VBL_BENCH_DIR``, else ``benchmarks/`` of the source tree
    (:func:`vbl.engine.registry.source_folder`)."""
    env = os.environ.get("VBL_BENCH_DIR", "").strip()
    return Path(env).resolve() if env else source_folder("benchmarks").resolve()


def benchmarks(folder: Path | None = None) -> dict[str, Path]:
    """``{name: script}`` of the real benchmarks: scripts with a ``__main__`` block."""
    folder = bench_dir() if folder is None else folder
    out = {}
    for p in sorted(folder.glob("*.py")):
        if p.name.startswith("_"):
            continue
        text = p.read_text(errors="replace")
        if "__name__ == \"__main__\"" in text or "__name__ == '__main__'" in text:
            out[p.stem] = p
    return out


@dataclass(frozen=True)
class Target:
    """How to read a benchmark's headline figure from its ``<name>.json`` and judge it.

    ``figure(result) -> (value, what)``; ``goal`` and ``higher`` (is a higher value better)
    give the verdict; ``goal=None``: the benchmark states no target."""

    figure: Callable[[dict], tuple[float, str]]
    goal: float | None = None
    higher: bool = True
    unit: str = ""


def _env(r: dict) -> tuple[float, str]:
    rows = [x for x in r["envs"]["shoot_pass"] if x.get("obs_used", True)]
    best = max(rows, key=lambda x: x["steps_per_s"])
    return best["steps_per_s"], f"two-robot steps/s with observation (batch {best['batch']})"


def _cva(r: dict) -> tuple[float, str]:
    rows = [x for x in r["rows"] if x["config"] == "default"]
    big = max(rows, key=lambda x: x["datasets"])
    return big["x_sippy_cpu"], f"x SIPPY CPU time, default identify, {big['datasets']} data sets"


def _qlearning(r: dict) -> tuple[float, str]:
    big = max(r["q_updates"], key=lambda x: x["learners"])
    return big["ratio_loop"], (f"x the per-transition NumPy loop, Q-updates at "
                               f"{big['learners']} learners")


def _learner(r: dict) -> tuple[float, str]:
    worst = max(r["rows"], key=lambda x: x["overhead"])
    return worst["overhead"], (f"x the raw env's CPU time per primitive, worst experiment "
                               f"({worst.get('experiment', '?')})")


def _camera(r: dict) -> tuple[float, str]:
    ratio = r["cameras"]["section3"]["cpu_ratio"]
    return 1.0 / ratio, ("x less CPU per Section 3 camera call than the polygon-clipping "
                         "reference camera")


def _compile(r: dict) -> tuple[float, str]:
    worst = max(r["rows"], key=lambda x: x["trace_cpu_s"] + x["compile_cpu_s"])
    name = worst.get("run", worst["experiment"])
    return worst["trace_cpu_s"] + worst["compile_cpu_s"], (
        f"CPU s to trace and compile the longest program ({name} {worst['function']})")


def _first_run(r: dict) -> tuple[float, str]:
    return r["cold"]["wall_s"], (f"s wall, `vbl reproduce --quick` with an empty compilation "
                                 f"cache (then {r['warm']['wall_s']:.0f} s warm; load "
                                 f"{r['cold']['load_average'][0]:.1f} at the start)")


def _ppo(r: dict) -> tuple[float, str]:
    best = max(r["rows"], key=lambda x: x["steps_per_s"])
    size = ""
    if "policy_params" in best:
        size = f", {best['policy_params']:,} + {best['value_params']:,} parameters"
    compiled = f", compile {best['compile_s']:.0f} s" if "compile_s" in best else ""
    return best["steps_per_s"], (f"PPO env steps/s ({best['task']}, {best['net']} networks"
                                 f"{size}{compiled})")


def _state_map(r: dict) -> tuple[float, str]:
    one = min(r["rows"], key=lambda x: x["learners"])
    return one["x_vs_numpy"], "x faster cell construction than vectorised NumPy (float64)"


def _sweep(r: dict) -> tuple[float, str]:
    rows = [x for x in r["rows"] if x["experiment"] == "table2_shoot_pass"
            and x["processes"] == 1 and x["devices"] == 2]
    big = max(rows, key=lambda x: x["learners"])
    return big["strong_efficiency"], (f"strong-scaling efficiency of 2 devices vs 1, Table 2's "
                                      f"training step at {big['learners']:,} learners")


def _render(r: dict) -> tuple[float, str]:
    rows = [x for x in r["rows"] if x["row"] == "pixel features"]
    mid = [x for x in rows if x["size"] == "128x120"] or rows
    best = max(mid, key=lambda x: x["frames_per_s"])
    return best["frames_per_s"], (f"frames/s with Section 3 features from pixels at "
                                  f"{best['size'].replace('x', ' x ')} (batch {best['batch']})")


TARGETS: dict[str, Target] = {
    "env_throughput": Target(_env, 1e6),
    "cva_throughput": Target(_cva, 100.0),
    "qlearning_throughput": Target(_qlearning, 50.0),
    "learner_throughput": Target(_learner, 1.5, higher=False),
    "camera_throughput": Target(_camera),
    "compile_time": Target(_compile, 60.0, higher=False),
    "first_run": Target(_first_run, 240.0, higher=False),
    "ppo_throughput": Target(_ppo),
    "state_map_build": Target(_state_map),
    "sweep_scaling": Target(_sweep),
    "render_throughput": Target(_render),
}
"""The headline figure of each benchmark and its target (the README's "Benchmarks")."""


def _number(v: float) -> str:
    return f"{v:,.0f}" if abs(v) >= 1000 else f"{v:.3g}"


def headline(name: str, out: Path) -> str:
    """One line: the benchmark's figure, its target and the verdict (met / not met), read
    from ``out/<name>.json``."""
    t = TARGETS.get(name)
    path = Path(out) / f"{name}.json"
    try:
        result: Any = json.loads(path.read_text())
    except (OSError, ValueError):
        result = None
    if t is None or result is None:
        return f"{name}: no figure read ({path.name} {'missing' if result is None else 'kept'})"
    try:
        value, what = t.figure(result)
        value = float(value)
    except (KeyError, ValueError, TypeError, ZeroDivisionError):
        return f"{name}: results in {path.name} (headline figure not found)"
    if t.goal is None:
        return f"{name}: {_number(value)} {what}; target: none stated"
    ok = value >= t.goal if t.higher else value <= t.goal
    if math.isnan(value):
        ok = False
    sign = ">=" if t.higher else "<="
    return (f"{name}: {_number(value)} {what}; target {sign} {_number(t.goal)}: "
            f"{'met' if ok else 'not met'}")


def _shadow(src: Path, out: Path) -> Path:
    """``OUT/.scripts/<tree>``: the source tree linked entry by entry, with a copy of the
    benchmark folder whose ``results`` is ``out``. Returns the copied benchmark folder."""
    root = out / ".scripts"
    if root.exists():
        shutil.rmtree(root)
    tree = root / "src"
    tree.mkdir(parents=True)
    for entry in src.parent.iterdir():
        if entry.name != src.name:
            (tree / entry.name).symlink_to(entry)
    bench = tree / src.name
    bench.mkdir()
    for p in src.iterdir():
        if p.suffix == ".py":
            shutil.copy2(p, bench / p.name)
    (bench / "results").symlink_to(out.resolve(), target_is_directory=True)
    return bench


def run_benchmarks(names: list[str], out: str | Path | None, quick: bool,
                   echo: Callable[[str], None] | None = None) -> list[str]:
    """Run the benchmarks ``names`` (all when empty) with results in ``out`` (default
    :data:`DEFAULT_OUT`); print each one's headline. Returns the names that failed."""
    echo = echo or (lambda text: print(text, flush=True))
    src = bench_dir()
    if not src.is_dir():
        raise EngineError(f"no benchmark folder at {src}: the benchmarks come with the source "
                          f"tree (pip install -e .), or set VBL_BENCH_DIR")
    known = benchmarks(src)
    bad = [n for n in names if n not in known]
    if bad:
        raise ParamError(f"unknown benchmark(s) {bad}; valid: {sorted(known)}")
    out = Path(out if out is not None else DEFAULT_OUT).absolute()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise EngineError(f"cannot write to benchmark folder {out}: {e.strerror or e}") from e
    in_place = out.resolve() == (src / "results").resolve()
    folder = src if in_place else _shadow(src, out)
    failed, lines = [], []
    try:
        for name in (names or list(known)):
            echo(f"== {name}")
            cmd = [sys.executable, str(folder / f"{name}.py")] + (["--quick"] if quick else [])
            if subprocess.run(cmd, cwd=folder.parent).returncode != 0:
                failed.append(name)
                lines.append(f"{name}: failed")
            else:
                lines.append(headline(name, out))
    finally:
        if not in_place:
            shutil.rmtree(out / ".scripts", ignore_errors=True)
    echo(f"\nbenchmarks (results in {out}):")
    for line in lines:
        echo("  " + line)
    return failed
