"""brax PPO as a deep-RL comparator of the tabular learners (issue: which state does a
learner need when other agents move?).

Two experiments, each a vmapped PPO program (:mod:`vbl.agents.ppo_programs`) with the
categorical policy of :mod:`vbl.agents.ppo`:

* ``ppo_comparator``: the two-robot task of Table 2 (shooter and passer) with three inputs,
  current features, the last 3 frames, and the CVA state vector of the tabular learner
  (its own identification per seed), with and without the curriculum (on
  ``env.start_difficulty``), at Table 2's experience (2.56 M primitives); beside the
  tabular results of Table 2 (current defaults, 16 seeds) and the paper.
* ``ppo_shooting``: the shooting task of Section 2 (100 s limit, fully random starts), with
  and without the curriculum (LEM for PPO), at the grid baseline's experience (~3 M
  primitives); beside the grid baseline (``grid_shooting``, 8 seeds).

Run: ``vbl run ppo_comparator --quick`` / ``vbl run ppo_shooting --quick``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from flax import struct

from vbl.agents.cva_state import CVAStateParams
from vbl.agents.ppo_programs import (
    InputChoice,
    PPORunParams,
    ci95,
    input_label,
    make_shoot_pass_program,
    make_shooting_program,
    plot_success_vs_steps,
    plot_two_robot_curves,
    welch_ci,
)
from vbl.agents.ppo_train import PPOParams
from vbl.engine import Experiment, ReportSection, register
from vbl.engine.cva_program import default_learner
from vbl.engine.paper import TABLE2
from vbl.envs.shoot_pass import ShootPassParams
from vbl.envs.shooting import ShootingParams
from vbl.params import section

PAPER = TABLE2
# Tabular greedy success %, mean +- 95 % CI over 16 seeds (docs/results/table2_q6488)
TABULAR = {"shoot": {"current": (16.5, 2.3), "cva": (16.8, 2.7)},
           "pass": {"current": (22.4, 6.7), "cva": (59.5, 4.3)}}
# Grid baseline greedy / near-greedy success %, 8 seeds (docs/results/grid_shooting)
GRID = {False: (15.9, 13.7, 26.3, 17.4), True: (23.7, 9.5, 45.9, 13.1)}
QUICK_PPO = {"ppo.num_envs": 16, "ppo.batch_size": 16, "ppo.num_minibatches": 2,
             "ppo.steps_per_chunk": 2, "ppo.eval_envs": 8, "run.final_eval_envs": 16,
             "run.num_chunks": 2}


@struct.dataclass
class ShootPassConfig:
    env: ShootPassParams = section(ShootPassParams, doc="the two-robot task (Table 2's)")
    inputs: InputChoice = section(InputChoice, doc="what PPO sees")
    cva: CVAStateParams = section(default_learner, doc="the tabular learner's CVA "
                                  "pipeline (collection, identification; its quantiser and "
                                  "runner are unused)")
    ppo: PPOParams = section(PPOParams, doc="brax PPO")
    run: PPORunParams = section(PPORunParams, doc="50 chunks x 51,200 = 2.56 M primitives")


@struct.dataclass
class ShootingConfig:
    env: ShootingParams = section(lambda: ShootingParams(max_steps=1000),
                                  doc="shooting, 100 s limit (the grid baseline's)")
    ppo: PPOParams = section(PPOParams, doc="brax PPO")
    run: PPORunParams = section(lambda: PPORunParams(num_chunks=60),
                                doc="60 chunks x 51,200 = 3.07 M primitives")


def _diff(a, b) -> str:
    m, h = welch_ci(a, b)
    verdict = "shown" if m - h > 0 else "reversed" if m + h < 0 else "not shown"
    return f"{m:+.1f} ± {h:.1f} ({verdict})"


def report_shoot_pass(res) -> ReportSection:
    sr = 100 * np.asarray(res.final["greedy_success_rate"])
    by, keys = {}, []
    for i, pt in enumerate(res.points):
        task = "pass" if pt.get("env.task_pass", res.config.env.task_pass) else "shoot"
        inp = input_label(pt.get("inputs.index", res.config.inputs.index))
        cur = bool(pt.get("ppo.curriculum.enabled", res.config.ppo.curriculum.enabled))
        by[task, inp, cur] = sr[i]
        keys.append((task, inp, cur))
    steps = int(np.asarray(res.curves["env_steps"])[0, -1, 0])
    rows = ["| task | input | curriculum | PPO greedy % | tabular Q %, Table 2 defaults, "
            "16 seeds | paper % |", "|---|---|---|---|---|---|"]
    for (task, inp, cur), x in by.items():
        m, h = ci95(x)
        tab = TABULAR[task].get(inp)
        rows.append(f"| {task} | {inp} | {'on' if cur else 'off'} | {m:.1f} ± {h:.1f} | "
                    f"{f'{tab[0]} ± {tab[1]}' if tab else '-'} | {PAPER[task].get(inp, '-')} |")
    adv = []
    for cur in (False, True):
        for task in ("shoot", "pass"):
            if not all((task, k, cur) in by for k in ("current", "stack", "cva")):
                continue
            adv.append(f"* {task}, curriculum {'on' if cur else 'off'}: PPO CVA − current "
                       f"{_diff(by[task, 'cva', cur], by[task, 'current', cur])}; stack − "
                       f"current {_diff(by[task, 'stack', cur], by[task, 'current', cur])} "
                       f"points (paper: CVA − current "
                       f"{PAPER[task]['cva'] - PAPER[task]['current']:+.1f})")
    for task in ("shoot", "pass"):
        pairs = [(inp, _diff(by[task, inp, True], by[task, inp, False]))
                 for inp in ("current", "stack", "cva")
                 if (task, inp, True) in by and (task, inp, False) in by]
        if pairs:
            adv.append(f"* {task}, curriculum on − off: "
                       + "; ".join(f"{inp} {d}" for inp, d in pairs) + " points")
    fig = plot_two_robot_curves(res.curves, keys, res.out_dir / "ppo_success_vs_steps.png",
                                "PPO, two-robot task")
    md = (f"brax PPO (categorical policy) on Table 2's task, {res.seeds} seeds, {steps:,} "
          "training primitives per learner; greedy = deterministic policy at the full start "
          "distribution (start difficulty 1), first episode from each of the final "
          "evaluation's fresh starts (mean ± 95 % CI).\n\n"
          + "\n".join(rows) + "\n\nDoes PPO show the CVA advantage (difference of means, "
          "Welch 95 % CI; shown = interval above 0, reversed = below 0)? And what does the "
          "curriculum change?\n\n" + "\n".join(adv))
    return ReportSection(markdown=md, figures=(fig, *res.figures))


def report_shooting(res) -> ReportSection:
    sr = 100 * np.asarray(res.final["greedy_success_rate"])
    labels, rows = [], ["| curriculum | PPO greedy % | grid Q greedy % | grid Q near-greedy % |",
                        "|---|---|---|---|"]
    for i, pt in enumerate(res.points):
        on = bool(pt.get("ppo.curriculum.enabled", res.config.ppo.curriculum.enabled))
        labels.append("with curriculum" if on else "without curriculum")
        m, h = ci95(sr[i])
        g = GRID[on]
        rows.append(f"| {'on' if on else 'off'} | {m:.1f} ± {h:.1f} | {g[0]} ± {g[1]} | "
                    f"{g[2]} ± {g[3]} |")
    steps = int(np.asarray(res.curves["env_steps"])[0, -1, 0])
    fig = plot_success_vs_steps(res.curves, labels, res.out_dir / "ppo_success_vs_steps.png",
                                "PPO, shooting (Section 2)")
    md = (f"brax PPO on the shooting task from fully random starts (100 s limit), "
          f"{res.seeds} seeds, {steps:,} training primitives per learner (grid baseline: "
          "~3 M); mean ± 95 % CI.\n\n" + "\n".join(rows))
    return ReportSection(markdown=md, figures=(fig, *res.figures))


EXPERIMENT = register(Experiment(
    name="ppo_comparator",
    description="brax PPO on the two-robot task: current features vs frame stack vs CVA state",
    default_config=ShootPassConfig(), make_program=make_shoot_pass_program,
    quick={**QUICK_PPO, "cva.collect_steps": 1000, "cva.cva.lag_max": 2},
    seeds=8, quick_seeds=2, paper_result=True, paper=PAPER, report=report_shoot_pass,
    sweep={"env.task_pass": [False, True], "inputs.index": [0, 1, 2],
           "ppo.curriculum.enabled": [False, True]},
    cost=300.0))  # s, cold --quick on 2 cores (compile-dominated; 1,389 s at load average 12)

SHOOTING = register(Experiment(
    name="ppo_shooting",
    description="brax PPO on the shooting task, with and without the curriculum",
    default_config=ShootingConfig(), make_program=make_shooting_program,
    quick={**QUICK_PPO, "env.max_steps": 100},
    seeds=8, quick_seeds=2, paper_result=True, report=report_shooting,
    sweep={"ppo.curriculum.enabled": [False, True]}, cost=150.0))  # s, cold --quick (guess)

def rerender(folder: str) -> Path:
    """Write ``report.md`` of a finished ``ppo_comparator`` run folder again with this
    module's report (curves rebuilt from its ``metrics.jsonl``): ``python
    experiments/ppo_comparator.py --rerender RUN_DIR``."""
    import dataclasses
    import json

    from vbl.engine.report import load_run, run_report

    exp, res, _ = load_run(folder)
    rows = [json.loads(line) for line in (Path(folder) / "metrics.jsonl").read_text()
            .splitlines() if line.strip()]
    rows = [r for r in rows if isinstance(r.get("chunk"), int)]
    chunks = 1 + max(r["chunk"] for r in rows)
    curves: dict = {}
    for r in rows:
        for k, st in r["metrics"].items():
            v = np.asarray(st["per_seed"], float)
            curves.setdefault(k, np.full((len(res.points), chunks, v.size), np.nan))[
                r["point"], r["chunk"]] = v
    res = dataclasses.replace(res, curves=curves, figures=())
    return run_report(exp, res)[1]


if __name__ == "__main__":
    import sys

    if len(sys.argv) == 3 and sys.argv[1] == "--rerender":
        print(rerender(sys.argv[2]))
    else:
        from vbl.cli import main_for

        main_for(EXPERIMENT)
