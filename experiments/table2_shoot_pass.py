"""Table 2: shooting and passing success with current features vs CVA state vectors.

Each learner (one seed) runs the Figure 11 pipeline in the two-robot env, then greedy
evaluation chunks from fresh starts: :mod:`vbl.engine.cva_program` (its defaults are
measured choices: docs/cva_learning.md, "Choices and why"). The default sweep, task x state
vector (4 rows of the table), is one compilation. Presets give the variants the README
reports (``--preset monte_carlo``: Monte Carlo values, the best published shooting result).

Run: ``vbl run table2_shoot_pass --quick`` or ``python experiments/table2_shoot_pass.py``.
"""

from __future__ import annotations

import numpy as np
from flax import struct

from vbl.agents.cva_state import CVAStateParams
from vbl.agents.qlearning import QRunnerParams
from vbl.engine import Experiment, register
from vbl.engine.cva_program import (
    POINT_KEYS,
    RENAMED_PARAMS,
    CVATrainParams,
    default_cva,
    default_table2_q,
    make_cva_program,
    migrate,
    state_label,
    task_label,
)
from vbl.engine.experiment import PaperRow, ReportSection
from vbl.engine.paper import TABLE2
from vbl.engine.report import seeds_cell
from vbl.envs.shoot_pass import ENV_TASKS, ShootPassParams
from vbl.params import param, section
from vbl.stats import welch_ci95
from vbl.sysid.params import PREDICTOR_OPTIONS


@struct.dataclass
class Table2Config:
    task: str = param("select", doc="learner role: shooter, passer, or 'select': the traced "
                      "env.task_pass picks the role per learner (one compilation for both "
                      "tasks)", static=True, choices=ENV_TASKS)
    cva: CVAStateParams = section(default_cva, doc="the Figure 11 state: CVA, filter, quantiser")
    q: QRunnerParams = section(default_table2_q, doc="the tabular Q-learner on that state")
    env: ShootPassParams = section(ShootPassParams, doc="the two-robot task")
    train: CVATrainParams = section(CVATrainParams, doc="run length and evaluation")


def _row(pt: dict, config) -> tuple[str, str, str]:
    """(task, state vector, the point's other settings) of a sweep point."""
    more = ", ".join(f"{k}={v}" for k, v in pt.items() if k not in POINT_KEYS)
    return task_label(pt, config), state_label(pt, config), more


def report(res) -> ReportSection:
    rows = ["| task | state vector | ours: greedy success % (mean ± 95% CI) | ours: last "
            "training chunk % | paper % | CVA (l, n*) ball / goal / other |",
            "|---|---|---|---|---|---|"]
    n_ev = res.config.train.eval_chunks  # the last curve points are the greedy chunks
    for i, pt in enumerate(res.points):
        task, state, more = _row(pt, res.config)
        greedy = seeds_cell(res.final["greedy_success_rate"][i], 100.0, ".1f")
        train = seeds_cell(res.curves["chunk_success"][i][-1 - n_ev], 100.0, ".1f")
        ident = " / ".join(
            f"{np.median(res.final[f'lag_{o}'][i]):.0f}, {np.median(res.final[f'n_{o}'][i]):.0f}"
            for o in res.config.cva.objects if f"lag_{o}" in res.final)
        label = f"{task} ({more})" if more else task
        rows.append(f"| {label} | {state} | {greedy} | {train} | {TABLE2[task][state]} | "
                    f"{ident if state == 'cva' else '-'} |")
    md = ("Table 2 (success rates, %), " + f"{res.seeds} seeds per row; greedy success = "
          "first episode from a fresh start of each of the learner's envs after training "
          "(CVA column: median selected lag and AIC order).\n\n" + "\n".join(rows))
    return ReportSection(markdown=md + _differences(res), figures=tuple(res.figures))


def _differences(res) -> str:
    """CVA state minus current features per task (and other settings), greedy success
    points with the Welch 95 % interval, beside the paper's difference."""
    arms: dict[tuple[str, str], dict[str, np.ndarray]] = {}
    for i, pt in enumerate(res.points):
        task, state, more = _row(pt, res.config)
        arms.setdefault((task, more), {})[state] = 100.0 * np.asarray(
            res.final["greedy_success_rate"][i])
    lines = []
    for (task, more), a in arms.items():
        if {"cva", "current"} <= set(a):
            d, h = welch_ci95(a["cva"], a["current"])
            paper = TABLE2[task]["cva"] - TABLE2[task]["current"]
            lines.append(f"| {task}{f' ({more})' if more else ''} | {d:+.1f} ± {h:.1f} | "
                         f"{'yes' if abs(d) > h else 'no'} | {paper:+.1f} |")
    if not lines:
        return ""
    return ("\n\nCVA state − current features, greedy success points (Welch 95 % interval; "
            "separated: the interval excludes 0):\n\n| task | vbl | separated | paper |\n"
            "|---|---|---|---|\n" + "\n".join(lines))


def paper_rows(res) -> list[PaperRow]:
    update = res.config.q.update
    values = {"q_learning": "", "monte_carlo": ", Monte Carlo values"}.get(update,
                                                                           f", {update}")
    rows = []
    for i, pt in enumerate(res.points):
        task, state, more = _row(pt, res.config)
        rows.append(PaperRow(
            f"Table 2, {'passing' if task == 'pass' else 'shooting'}, "
            f"{'CVA state' if state == 'cva' else 'current features'}{values}"
            f"{', ' + more if more else ''}: greedy success %", str(TABLE2[task][state]),
            seeds_cell(res.final["greedy_success_rate"][i], 100.0, ".1f")))
    return rows


EXPERIMENT = register(Experiment(
    name="table2_shoot_pass",
    description="Table 2: shoot/pass success, current features vs CVA state vectors",
    default_config=Table2Config(),
    make_program=make_cva_program,
    # --quick: the full run's programs (one compilation serves both) for 1/8 of its chunks,
    # schedules scaled (docs/findings/table2_shoot_pass.md, "Experience")
    quick={"train.num_chunks": 50, "q.exploration.transition_steps": 3750.0,
           "train.lr_scale.transition_begin": 35.0, "train.lr_scale.transition_steps": 5.0},
    seeds=16,
    quick_seeds=16,
    paper_result=True,
    cost=300.0,  # s of a cold --quick run on 2 cores (compile + ~1 min of training)
    paper=TABLE2,
    report=report,
    paper_rows=paper_rows,
    presets={"monte_carlo": {"q.update": "monte_carlo", "q.learning_rate": 0.1}},
    migrate=migrate, renamed_params=RENAMED_PARAMS,
    # chunk_success: the episodes that finished in a chunk (training chunks: with exploration;
    # the last train.eval_chunks: greedy, no learning); folders written before read through this
    renamed_metrics={"success_rate": "chunk_success"},
    # parameters added after run folders were written: the values of the code before them
    legacy_values={"cva.keep_beyond_order": False,
                   "cva.ident.lag_rule": "paper", "cva.ident.collinear_tol": 1e-8,
                   "q.update": "q_learning", "q.mc_log": 128, "env.start_difficulty": 1.0,
                   "env.noise_on.aim": True,
                   **{"cva.ident." + k: v for k, v in PREDICTOR_OPTIONS.items()},
                   **{f"env.noise_on.{n}": False for n in ("pixel", "slip", "wobble")}},
    sweep={"env.task_pass": [False, True], "cva.use_cva": [False, True]},
    removed_params={"cva.cancor_weight": False},  # docs/findings/pruned_variants.md
))

if __name__ == "__main__":
    from vbl.cli import main_for

    main_for(EXPERIMENT)
