"""Table 2's report: the success table (greedy, near-greedy and random policies, primitives
per decision) with the paper's column, CVA minus current features per task, and the
velocity oracle's criterion (:data:`ORACLE_MARGIN`); and the rows beside the paper's
numbers for ``vbl reproduce``'s headline table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from vbl.engine.experiment import PaperRow, ReportSection
from vbl.engine.report import claim, rate_cell, seeds_cell
from vbl.programs.paper import TABLE2
from vbl.programs.table2 import POINT_KEYS, VELOCITY, state_label, task_label
from vbl.programs.tabular import decision_primitives

__all__ = ["ORACLE_MARGIN", "report", "paper_rows"]

#: The ablation probe's results (benchmarks/probes/table2_ablation.py), in a source tree.
ABLATION = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "table2_ablation.json"

#: Greedy success points by which the velocity oracle must beat the current features for
#: the task to show the paper's claim (docs/findings/table2_shoot_pass.md, "Controls").
ORACLE_MARGIN = 20.0


def _row(pt: dict, config) -> tuple[str, str, str]:
    """(task, state vector, the point's other settings) of a sweep point."""
    more = ", ".join(f"{k}={v}" for k, v in pt.items() if k not in POINT_KEYS)
    return task_label(pt, config), state_label(pt, config), more


def report(res) -> ReportSection:
    objects = " / ".join(res.config.cva.objects)
    rows = ["| task | state vector | greedy % | near-greedy % | random % | last training "
            f"chunk % | primitives per decision: training / greedy | paper % | CVA (l, n*): "
            f"{objects} |", "|---|---|---|---|---|---|---|---|---|"]
    fin = res.final
    for i, pt in enumerate(res.points):
        task, state, more = _row(pt, res.config)
        cells = [rate_cell(fin[m][i], 100.0, ".1f") for m in
                 ("greedy_success", "near_greedy_success", "random_success")]
        train = rate_cell(res.curves["train_success"][i][-1], 100.0, ".1f")
        per = (f"{seeds_cell(decision_primitives(res, i), fmt='.2f')} / "
               f"{seeds_cell(fin['greedy_primitives_per_decision'][i], fmt='.2f')}")
        ident = " / ".join(
            f"{np.median(fin[f'lag_{o}'][i]):.0f}, {np.median(fin[f'n_{o}'][i]):.0f}"
            for o in res.config.cva.objects if f"lag_{o}" in fin)
        label = f"{task} ({more})" if more else task
        rows.append(f"| {label} | {state} | {' | '.join(cells)} | {train} | {per} | "
                    f"{TABLE2[task].get(state, '-')} | "
                    f"{ident if state.startswith('cva') else '-'} |")
    ev = res.config.train
    md = (f"Table 2 (success rates, %), {res.seeds} seeds per row, mean ± 95 % CI: the "
          f"first episode from each of {ev.eval_rounds} x {res.config.agent.num_envs} fresh "
          "starts after training, the same starts for the greedy policy, the near-greedy "
          f"one (a uniform action with probability {ev.eval_epsilon}) and the uniformly "
          "random one. Primitives per decision: primitives per macro action of the training "
          "episodes (whole run) and of the greedy policy; an action ends when what the "
          "state map perceives changes (for the CVA state: not its command terms). CVA "
          "column: median selected lag and AIC order.\n\n" + "\n".join(rows))
    return ReportSection(markdown=md + _differences(res) + _ablation(res.config.agent.update),
                         figures=tuple(res.figures))


def _ablation(update: str) -> str:
    """The quick-scale ablation's finding for the run's update rule ``update``
    (``benchmarks/probes/table2_ablation.py``) from its committed results file, where the
    source tree holds it; "" otherwise."""
    if not ABLATION.is_file():
        return ""
    diffs = json.loads(ABLATION.read_text())["differences"].get(update, {})
    if not {"figure11", "defaults"} <= set(diffs):
        return ""

    def gap(variant: str, task: str) -> str:
        return "{:+.1f} ± {:.1f}".format(*diffs[variant][f"{task}: cva + true velocity - oracle"])

    learner = {"q_learning": "one-step Q-learning", "monte_carlo": "Monte Carlo values"}.get(
        update, f"agent.update={update}")
    return ("\n\nWhere the CVA state loses information (the ablation at quick scale, "
            f"{learner}, 16 seeds: `python benchmarks/probes/table2_ablation.py`, "
            "docs/findings/table2_shoot_pass.md): the CVA state identified with the ball's "
            "true velocity minus the velocity oracle, greedy success points, is "
            f"{gap('figure11', 'shoot')} (shooting) and {gap('figure11', 'pass')} (passing) "
            "with a CVA block per object, and "
            f"{gap('defaults', 'shoot')} and {gap('defaults', 'pass')} with the ball's CVA "
            "block beside the goal's and the other robot's current features, the state of "
            "this experiment's defaults.")


def _differences(res) -> str:
    """CVA state minus current features per task (and other settings), greedy success
    points with the Welch 95 % interval, beside the paper's difference."""
    arms: dict[tuple[str, str], dict[str, np.ndarray]] = {}
    for i, pt in enumerate(res.points):
        task, state, more = _row(pt, res.config)
        arms.setdefault((task, more), {})[state] = 100.0 * np.asarray(
            res.final["greedy_success"][i])
    lines, oracle = [], []
    for (task, more), a in arms.items():
        name = f"{task}{f' ({more})' if more else ''}"
        if {"cva", "current"} <= set(a):
            paper = TABLE2[task]["cva"] - TABLE2[task]["current"]
            lines.append(f"| {name} | {claim(a['cva'], a['current'], fmt='.1f')} | "
                         f"{paper:+.1f} |")
        vel = "current" + VELOCITY
        if {vel, "current"} <= set(a):
            oracle.append(f"| {name} | {claim(a[vel], a['current'], fmt='.1f')} | "
                          f"{claim(a[vel], a['current'] + ORACLE_MARGIN, fmt='.1f')} |")
    md = ""
    if lines:
        md += ("\n\nDoes the CVA state beat the current features? Greedy success points, "
               "CVA − current, Welch 95 % interval:\n\n| task | vbl | paper |\n|---|---|---|\n"
               + "\n".join(lines))
    if oracle:
        md += ("\n\nWhat must hold for the task to show the paper's claim at all: the "
               "velocity oracle (current features + the ball's true velocity) beats the "
               f"current features, by at least {ORACLE_MARGIN:.0f} points (greedy success "
               "points, oracle − current, and oracle − current − "
               f"{ORACLE_MARGIN:.0f}, Welch 95 % interval):\n\n| task | oracle beats "
               f"current | by >= {ORACLE_MARGIN:.0f} points |\n|---|---|---|\n"
               + "\n".join(oracle))
    elif "ball_velocity" not in res.sweep and not res.config.ball_velocity:
        md += ("\n\nThe velocity oracle, the control that says whether this task can show "
               "the paper's claim at all, is not in this run (`--quick` runs the paper's "
               "rows; the full `vbl reproduce` runs the control, and `--sweep "
               "ball_velocity=false,true` adds it here).")
    return md


def paper_rows(res) -> list[PaperRow]:
    update = res.config.agent.update
    values = {"q_learning": "", "monte_carlo": ", Monte Carlo values"}.get(update,
                                                                           f", {update}")
    rows = []
    for i, pt in enumerate(res.points):
        task, state, more = _row(pt, res.config)
        names = {"cva": "CVA state", "current": "current features",
                 "current" + VELOCITY: "velocity oracle (current features + true velocity)",
                 "cva" + VELOCITY: "CVA state of features + true velocity"}
        rows.append(PaperRow(
            f"Table 2, {'passing' if task == 'pass' else 'shooting'}, "
            f"{names.get(state, state)}{values}"
            f"{', ' + more if more else ''}: greedy success %",
            str(TABLE2[task].get(state, "-")),
            rate_cell(res.final["greedy_success"][i], 100.0, ".1f")))
    return rows
