"""Grid baseline: Q-learning to shoot on the hand-designed 319-state grid, with and without
Learning from Easy Missions (the earlier work the paper compares against, Figure 5's grid).

Each learner trains one Q-table (319 states x 9 primitives; one action = repeat a primitive
until the grid state changes, asynchronously: a learner step is one primitive of every
robot) with ``agent.num_envs`` parallel robots and Peng's Q(lambda), from fully random
starts within 100 s: the preset :mod:`vbl.programs.baselines` (measured choices:
docs/findings/grid_shooting.md). After every ``train.eval_every`` chunks the near-greedy
policy is evaluated on fresh starts: the ``eval_success`` curve against training trials.
The default sweep compares LEM off (``agent.lem.initial_difficulty`` = the cap: every
episode at the task difficulty, in the same compiled program) with LEM on (episodes start
easy). ``final``: greedy, near-greedy and random policy success. Other task difficulties:
``--set train.eval_difficulty=D --set agent.lem.max_difficulty=D --sweep
agent.lem.initial_difficulty=D,0``.

Run: ``vbl run grid_shooting [--quick]`` or ``python experiments/grid_shooting.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from flax import struct

from vbl.agents.qlearning import QRunnerParams
from vbl.engine import Experiment, ReportSection, RunResult, register
from vbl.engine.experiment import PaperRow
from vbl.engine.report import claim, rate_cell, seeds_cell
from vbl.envs.shooting import ShootingParams
from vbl.params import section
from vbl.programs.baselines import (
    TASK_DIFFICULTY,
    grid_agent,
    grid_env,
    grid_program,
    grid_space,
    grid_train,
)
from vbl.programs.curves import (
    LEM_PATH,
    CurveReportParams,
    curve_description,
    lem_label,
    lem_verdict,
    plot_success_vs_trials,
    trials_to_levels,
)
from vbl.programs.tabular import TabularTrainParams, curve_metric, decision_primitives
from vbl.spaces.grid import NUM_GRID_STATES, GridParams
from vbl.stats import mean_ci95


@struct.dataclass
class GridShootingConfig:
    env: ShootingParams = section(grid_env, doc="shooting task (Section 2), 100 s time limit")
    grid: GridParams = section(grid_space, doc="grid boundaries (319 states)")
    agent: QRunnerParams = section(grid_agent, doc="Q-learning, macro actions, LEM")
    train: TabularTrainParams = section(grid_train, doc="run length and evaluation")
    report: CurveReportParams = section(CurveReportParams, doc="report settings")


def report(res: RunResult) -> ReportSection:
    levels = [float(v) for v in np.atleast_1d(res.config.report.success_levels)]
    window = int(res.config.report.smooth_chunks)
    fig = plot_success_vs_trials(res, levels[0], Path(res.out_dir) / "grid_shooting_lem.png",
                                 "Grid Q-learning shooting")
    fin, names = res.final, [lem_label(v, res.config) for v in res.points]
    # the random policy sees the same starts at every sweep point: average over points
    rnd = np.mean(np.asarray(fin["random_success"], float), axis=0)
    runs = {n: float(res.curves["episodes"][p].sum(axis=0).mean()) for p, n in enumerate(names)}
    reach = {n: trials_to_levels(res, p, levels, window) for p, n in enumerate(names)}
    md = [f"Learned policies on fresh starts at start difficulty "
          f"{res.config.train.eval_difficulty} (1: fully random), {res.seeds} seeds, "
          f"mean ± 95% CI; {NUM_GRID_STATES} grid states.", "",
          f"Near-greedy: a uniform action with probability {res.config.train.eval_epsilon} "
          "(breaks cycles between aliased grid states; on an aliased state space the best "
          "memoryless policy can be stochastic).", "",
          "| policy | greedy success | near-greedy success | training trials | primitives "
          "per decision: training / greedy |", "|---|---|---|---|---|"]
    md += [f"| {n} | {rate_cell(fin['greedy_success'][p])} | "
           f"{rate_cell(fin['near_greedy_success'][p])} | {runs[n]:.0f} | "
           f"{seeds_cell(decision_primitives(res, p), fmt='.2f')} / "
           f"{seeds_cell(fin['greedy_primitives_per_decision'][p], fmt='.2f')} |"
           for p, n in enumerate(names)]
    md += [f"| random policy | {rate_cell(rnd)} | | | |", "",
           f"Training trials (episodes) until {curve_description(res)[0]}, averaged over the "
           f"last {window} chunks, first reaches each level: median over the seeds (a seed "
           "that never reaches it counts as slowest) and seeds reaching it.", "",
           "| policy | " + " | ".join(f"trials to {lv:.0%}" for lv in levels) + " |",
           "|---|" + "---|" * len(levels)]
    for n in names:
        md.append(f"| {n} | " + " | ".join(
            f"{t:.0f} ({k}/{s})" if np.isfinite(t) else f"not reached ({k}/{s})"
            for t, k, s in (reach[n][lv] for lv in levels)) + " |")
    md += ["", "What must hold (the paper gives no number for this baseline):", ""]
    for kind, metric in (("greedy", "greedy_success"), ("near-greedy", "near_greedy_success")):
        best = max(range(len(names)), key=lambda p: mean_ci95(fin[metric][p])[0])
        md.append(f"* the {kind} policy ({names[best]}) shoots above the random policy: "
                  f"{claim(fin[metric][best], rnd)};")
    if {"with LEM", "without LEM"} <= set(names) and curve_metric(res.curves) != "eval_success":
        md.append("* LEM reaches each level in fewer trials: not measured at this scale (the "
                  "evaluation curve is off; the training success runs at LEM's own, easier "
                  "starts).")
    elif {"with LEM", "without LEM"} <= set(names):
        for lv in levels:
            verdict = lem_verdict(reach["with LEM"][lv][0], reach["without LEM"][lv][0],
                                  runs["without LEM"], runs["with LEM"])
            md.append(f"* LEM reaches {lv:.0%} in fewer trials: {verdict}.")
    return ReportSection("\n".join(md), (fig,))


def paper_rows(res: RunResult) -> list[PaperRow]:
    rows = [PaperRow(f"Grid baseline (319 states), {lem_label(pt, res.config)}: greedy / "
                     "near-greedy success", "none given (the earlier work's learner)",
                     f"{rate_cell(res.final['greedy_success'][i])} / "
                     f"{rate_cell(res.final['near_greedy_success'][i])}")
            for i, pt in enumerate(res.points)]
    rnd = np.mean(np.asarray(res.final["random_success"], float), axis=0)
    return rows + [PaperRow("Grid baseline, random policy: success", "-",
                            rate_cell(rnd))]


EXPERIMENT = register(Experiment(
    name="grid_shooting",
    description="grid-baseline Q-learning shooting (319 states), with and without LEM",
    default_config=GridShootingConfig(),
    make_program=grid_program,
    sweep={LEM_PATH: [TASK_DIFFICULTY, 0.0]},
    # --quick: the full run's programs for its first 24 chunks (LEM's first crossings)
    quick={"train.num_chunks": 24},
    seeds=8,
    quick_seeds=8,
    paper_result=True,
    paper={"baseline": "the earlier work's hand-designed grid (grid lines of Figure 5)"},
    report=report,
    headline=("greedy_success", "near_greedy_success", "random_success"),
    paper_rows=paper_rows,
))

if __name__ == "__main__":
    from vbl.cli import main_for

    main_for(EXPERIMENT)
