"""Probe: where Table 2's CVA state loses to the velocity oracle (an ablation at quick scale).

What it measures: ``table2_shoot_pass --quick`` (16 seeds, shooting and passing) with one
step of the CVA state's construction changed at a time, with one-step Q-learning and with
Monte Carlo values (the ``monte_carlo`` preset): greedy success of the CVA state and of the
CVA state identified from the features plus the ball's true velocity, beside the velocity
oracle (current features + true velocity) and the current features of the default run,
and the training episodes' primitives per decision. A gap between "CVA + true velocity"
and the oracle is lost in how the state is built and quantised, not in estimating the
velocity.

Variants (each the defaults with one change; the current-feature rows do not depend on
them and come from the default run):

* ``index_ends_actions``: a macro action ends when the state's index changes, command
  terms included (the rule before the perceived index; a state map of this probe);
* ``no_command_terms``: ``cva.command_terms=False``: the state without the command terms;
* ``cancor_weights``: ``cva.code_weights=cancor``;
* ``aic_order``: ``cva.keep_beyond_order=False``: the components beyond the AIC order are 0;
* ``ball_4``: ``cva.n_used_objects=(4, 4, 4)``: the ball's 4 leading components.

Not an experiment and not a benchmark; run from the repository root:

    python benchmarks/probes/table2_ablation.py [--out runs/table2_ablation]
        [--variants NAME ...] [--updates q_learning monte_carlo] [--tiny]

Writes ``benchmarks/results/table2_ablation.json`` (``--tiny``: a smoke test at toy size
that writes into ``--out`` only). Cost: about 45 min on 2 cores (12 quick runs). Cited by
docs/findings/table2_shoot_pass.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
RESULT = ROOT / "benchmarks" / "results" / "table2_ablation.json"

VARIANTS = {
    "defaults": {},
    "index_ends_actions": {},
    "no_command_terms": {"cva.command_terms": False},
    "cancor_weights": {"cva.code_weights": "cancor"},
    "aic_order": {"cva.keep_beyond_order": False},
    "ball_4": {"cva.n_used_objects": (4, 4, 4)},
}
UPDATES = ("q_learning", "monte_carlo")
TINY = {"agent.num_envs": 4, "agent.chunk_steps": 10, "env.max_steps": 10,
        "train.num_chunks": 2, "train.eval_rounds": 1, "cva.collect_steps": 600,
        "cva.quantizer.group_codes": (4, 2, 2), "cva.quantizer.kmeans_iters": 1}


def experiment(variant: str):
    """Table 2's experiment, or it on the state map whose index ends actions."""
    from vbl.agents.state_maps import CVAMap
    from vbl.engine.registry import load_script
    from vbl.programs.table2 import table2_env
    from vbl.programs.tabular import make_tabular_program

    exp = load_script(ROOT / "experiments" / "table2_shoot_pass.py").EXPERIMENT
    if variant != "index_ends_actions":
        return exp

    class IndexEndsActions(CVAMap):
        def perceived(self, obs, c):
            return obs["index"]

    return dataclasses.replace(exp, name="table2_index_ends_actions", make_program=lambda cfg:
                               make_tabular_program(IndexEndsActions(
                                   table2_env(cfg.task, cfg.ball_velocity), cfg.cva), cfg))


def rows(res) -> dict[str, dict]:
    """Per row ("shoot, cva + true velocity", ...): greedy success per seed (%) and the
    training episodes' primitives per decision per seed."""
    from vbl.programs.table2 import state_label, task_label
    from vbl.programs.tabular import decision_primitives

    out = {}
    for i, pt in enumerate(res.points):
        name = f"{task_label(pt, res.config)}, {state_label(pt, res.config)}"
        out[name] = {"greedy": (100.0 * np.asarray(res.final["greedy_success"][i])).tolist(),
                     "primitives_per_decision": decision_primitives(res, i).tolist()}
    return out


def run(variant: str, update: str, out: Path, tiny: bool) -> dict[str, dict]:
    from vbl.engine.runner import run_experiment

    exp = experiment(variant)
    sets = dict(VARIANTS[variant], **(TINY if tiny else {}))
    # the variants change the CVA state only: their current-feature rows are the defaults'
    sweep = None if variant == "defaults" else {
        "env.task_pass": [False, True], "cva.use_cva": [True], "ball_velocity": [False, True]}
    if tiny:  # one compilation: both state vectors, no velocity control
        sweep = {"cva.use_cva": [False, True], "ball_velocity": [False]}
    res = run_experiment(exp, sets=sets, sweep=sweep, quick=True, seeds=2 if tiny else None,
                         out=out / f"{variant}-{update}", overwrite=True, quiet=True,
                         plots=False, preset=None if update == "q_learning" else update)
    return rows(res)


def gaps(results: dict) -> dict:
    """Greedy success points, CVA + true velocity minus the oracle and CVA minus current
    features, per variant, update and task (Welch 95 % interval)."""
    from vbl.stats import welch_ci95

    out = {}
    for update, by_variant in results.items():
        base = by_variant.get("defaults")
        if base is None:
            continue
        for variant, r in by_variant.items():
            for task in ("shoot", "pass"):
                pairs = {"cva + true velocity - oracle": (f"{task}, cva + true velocity",
                                                          f"{task}, current + true velocity"),
                         "cva - current": (f"{task}, cva", f"{task}, current")}
                for what, (a, b) in pairs.items():
                    if a in r and b in base:
                        d, h = welch_ci95(np.asarray(r[a]["greedy"]),
                                          np.asarray(base[b]["greedy"]))
                        out.setdefault(update, {}).setdefault(variant, {})[
                            f"{task}: {what}"] = [float(d), float(h)]
    return out


def table(results: dict, diffs: dict) -> str:
    lines = ["| update | variant | row | greedy % | primitives per decision |",
             "|---|---|---|---|---|"]
    for update, by_variant in results.items():
        for variant, r in by_variant.items():
            for row, v in r.items():
                g, p = np.asarray(v["greedy"]), np.asarray(v["primitives_per_decision"])
                lines.append(f"| {update} | {variant} | {row} | {g.mean():.1f} | "
                             f"{p.mean():.2f} |")
    for update, by_variant in diffs.items():
        for variant, d in by_variant.items():
            for what, (m, h) in d.items():
                lines.append(f"| {update} | {variant} | {what} | {m:+.1f} ± {h:.1f} | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/table2_ablation", help="folder of the run folders")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--updates", nargs="+", default=list(UPDATES), choices=list(UPDATES))
    ap.add_argument("--tiny", action="store_true", help="smoke-test size (2 seeds, 2 chunks)")
    args = ap.parse_args(argv)
    if args.tiny:
        args.variants, args.updates = ["index_ends_actions"], ["q_learning"]
    out = Path(args.out)
    dest = out / "table2_ablation.json" if args.tiny else RESULT
    dest.parent.mkdir(parents=True, exist_ok=True)
    results: dict = {}
    for update in args.updates:
        for variant in args.variants:
            results.setdefault(update, {})[variant] = run(variant, update, out, args.tiny)
            diffs = gaps(results)  # written after every run: a stopped probe keeps its rows
            dest.write_text(json.dumps({"results": results, "differences": diffs}, indent=1)
                            + "\n")
            print(f"{update} / {variant}: done", flush=True)
    print(table(results, gaps(results)))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    sys.exit(main())
