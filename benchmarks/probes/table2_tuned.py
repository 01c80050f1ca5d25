"""Probe: Table 2 with each row's learner tuned at an equal budget (``vbl tune``).

Table 2's defaults (one-step Q-learning's step size, discount and final exploration rate)
were chosen by the mean over its rows, so no row has its own best learner. Here each of
the eight rows (task x state vector) gets its own search at ``--quick`` scale with the
same budget: ``TRIALS`` random settings of ``SPACE`` x ``SEEDS`` seeds in one batch (one
compilation), then the best setting and the config's own values on ``CONFIRM`` fresh
seeds (``vbl tune``'s confirmation, the same seeds for both). The comparison between
state vectors is then made between their confirmed best learners.

Not an experiment and not a benchmark; run from the repository root:

    python benchmarks/probes/table2_tuned.py [--out runs/table2_tuned] [--rows NAME ...]
    python benchmarks/probes/table2_tuned.py --table    # the note's table, from the JSON
    python benchmarks/probes/table2_tuned.py --tiny --out DIR   # a smoke test

Each row is one ``vbl tune`` process (its command is in the results file); the probe
writes ``benchmarks/results/table2_tuned.json`` (per row: the search's settings, the best
values, the per-seed greedy success of the best values and of the defaults on the fresh
seeds; the table's means and differences in points under ``statistics``), keeping rows
of earlier invocations it does not rerun (``--tiny`` writes into ``--out`` only). Cited by
docs/findings/table2_shoot_pass.md.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results" / "table2_tuned.json"
EXPERIMENT = "table2_shoot_pass"
#: the searched parameters of the one-step learner (defaults 0.25, 0.99, 0.05)
SPACE = ("agent.learning_rate=0.05..0.8:log", "agent.discount=0.9..0.999",
         "agent.exploration.end_value=0.01..0.2")
TRIALS, SEEDS, CONFIRM = 12, 8, 16
METRIC = "greedy_success"
STATES = {"current": (False, False), "current + true velocity": (False, True),
          "cva": (True, False), "cva + true velocity": (True, True)}
ROWS = {f"{task}, {state}": {"env.task_pass": task == "pass", "cva.use_cva": cva,
                             "ball_velocity": vel}
        for task in ("shoot", "pass") for state, (cva, vel) in STATES.items()}
TINY = {"agent.num_envs": 4, "agent.chunk_steps": 10, "env.max_steps": 10,
        "train.num_chunks": 2, "train.eval_rounds": 1, "cva.collect_steps": 600,
        "cva.quantizer.group_codes": (4, 2, 2), "cva.quantizer.kmeans_iters": 1}


def _value(v) -> str:
    if isinstance(v, tuple):
        return "(" + ",".join(map(str, v)) + ")"
    return str(v).lower() if isinstance(v, bool) else str(v)


def command(row: str, out: Path, tiny: bool) -> list[str]:
    """The ``vbl tune`` command of ``row`` into ``out``."""
    sets = {**ROWS[row], **(TINY if tiny else {})}
    trials, seeds, confirm = (2, 2, 2) if tiny else (TRIALS, SEEDS, CONFIRM)
    argv = ["vbl", "tune", EXPERIMENT, "--quick", "--trials", str(trials), "--batch",
            str(trials), "--seeds", str(seeds), "--confirm-seeds", str(confirm),
            "--sampler", "random", "--metric", METRIC, "--quiet", "--out", str(out)]
    for s in SPACE:
        argv += ["--space", s]
    for p, v in sets.items():
        argv += ["--set", f"{p}={_value(v)}"]
    return argv


def run(row: str, out: Path, tiny: bool) -> dict:
    """Tune ``row`` into ``out / <row>`` (a finished search is read, not run again)."""
    folder = out / row.replace(", ", "-").replace(" + ", "+").replace(" ", "_")
    argv = command(row, folder, tiny)
    if not (folder / "summary.json").exists():
        vbl = [sys.executable, "-m", "vbl.cli"]  # the installed `vbl` of this interpreter
        subprocess.run(vbl + argv[1:] + (["--resume"] if folder.exists() else []),
                       check=True, cwd=ROOT)
    sm = json.loads((folder / "summary.json").read_text())
    shown = command(row, Path("runs") / "table2_tuned" / folder.name, tiny)
    return {"command": " ".join(shlex.quote(w) for w in shown),
            "best": sm["params"], "defaults": sm["defaults"]["params"],
            "tuned": sm["confirmation"]["per_seed"], "default": sm["defaults"]["per_seed"],
            "search": sm["search"]["per_seed"], "learner_chunks":
            sm["compute"]["learner_chunks"]}


def _interval(pair) -> str:
    return "{:.1f} ± {:.1f}".format(*pair)


def _difference(pair) -> str:
    return "{:+.1f} ± {:.1f}".format(*pair)


def table(data: dict) -> str:
    """Per row: the defaults' and the tuned learner's greedy success % on the same fresh
    seeds, their difference (Welch 95 %) and the best values; then :func:`comparisons`."""
    stats = statistics(data["rows"])["rows"]
    lines = ["| row | defaults % | tuned % | tuned − defaults | step size | discount | "
             "final epsilon |", "|---|---|---|---|---|---|---|"]
    for row, r in data["rows"].items():
        st, b = stats[row], r["best"]
        lines.append(f"| {row} | {_interval(st['defaults'])} | {_interval(st['tuned'])} | "
                     f"{_difference(st['tuned - defaults'])} | "
                     f"{b['agent.learning_rate']:.3f} | {b['agent.discount']:.3f} | "
                     f"{b['agent.exploration.end_value']:.3f} |")
    return "\n".join(lines + [""] + comparisons(data["rows"]))


#: Table 2's comparisons: (name, row a, row b) within a task, a minus b
COMPARISONS = (("CVA − current", "cva", "current"),
               ("velocity oracle − current", "current + true velocity", "current"),
               ("CVA + true velocity − velocity oracle", "cva + true velocity",
                "current + true velocity"))


def statistics(rows: dict) -> dict:
    """The table's numbers in greedy success points: per row the defaults' and the tuned
    learner's mean and 95 % half-width and their Welch difference; per task and comparison
    the Welch differences between rows, with the defaults and tuned."""
    from vbl.stats import mean_ci95, welch_ci95

    pct = {row: {k: 100 * np.asarray(r[k], np.float64) for k in ("default", "tuned")}
           for row, r in rows.items()}
    out = {"rows": {row: {"defaults": list(mean_ci95(v["default"])),
                          "tuned": list(mean_ci95(v["tuned"])),
                          "tuned - defaults": list(welch_ci95(v["tuned"], v["default"]))}
                    for row, v in pct.items()}, "comparisons": {}}
    for task in ("shoot", "pass"):
        for name, a, b in COMPARISONS:
            ra, rb = pct.get(f"{task}, {a}"), pct.get(f"{task}, {b}")
            if ra is not None and rb is not None:
                out["comparisons"][f"{task}: {name}"] = {
                    k: list(welch_ci95(ra[k], rb[k])) for k in ("default", "tuned")}
    return out


def comparisons(rows: dict) -> list[str]:
    """Table 2's differences between rows (greedy success points, Welch 95 %), between the
    rows' default learners and between their tuned ones (:func:`statistics`)."""
    lines = ["| task | comparison | defaults | tuned |", "|---|---|---|---|"]
    for key, st in statistics(rows)["comparisons"].items():
        task, name = key.split(": ", 1)
        lines.append(f"| {task} | {name} | {_difference(st['default'])} | "
                     f"{_difference(st['tuned'])} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "table2_tuned")
    p.add_argument("--rows", nargs="+", choices=list(ROWS), default=list(ROWS))
    p.add_argument("--tiny", action="store_true", help="a smoke test at toy size")
    p.add_argument("--table", action="store_true", help="print the table of the results file")
    args = p.parse_args(argv)
    if args.table:
        print(table(json.loads(RESULTS.read_text())))
        return 0
    rows = ["shoot, current"] if args.tiny else args.rows
    target = args.out / "table2_tuned.json" if args.tiny else RESULTS
    data = json.loads(target.read_text()) if target.exists() else {}
    data.update({"experiment": EXPERIMENT, "space": list(SPACE), "trials": TRIALS,
                 "seeds": SEEDS, "confirm_seeds": CONFIRM, "metric": METRIC})
    data.setdefault("rows", {})
    for row in rows:
        data["rows"][row] = run(row, args.out, args.tiny)
        data["statistics"] = statistics(data["rows"])
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(data, indent=1) + "\n")
    print(table(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())
