"""Table 1: local predictive models of the goal, the ball and another robot by CVA.

A learner moves with random (view-keeping) actions while it observes (a) the goal,
(b) a rolling ball (kicked now and then by a third party), (c) another robot doing a
random walk, (d) another robot that moves to the ball (``vbl.envs.collect``). Each learner
(one seed) collects one data set per row and identifies it with the CVA + AIC + lag rule of
``vbl.sysid.identify`` inside its program (:mod:`vbl.programs.identification`; outputs in
units of ``y_unit`` px, areas as sqrt(area), see ``docs/two_robot_task.md``); the engine
vmaps the learners over seeds and sweep points. The report gives l, n, log det R and AIC,
mean ± 95 % interval over seeds, beside the paper's Table 1, and checks the qualitative claims.
The paper's plain CVA recipe beside the projected one: ``--sweep
ident.method=projected,paper``.

Run: ``vbl run table1_identification [--quick]`` or
``python experiments/table1_identification.py``.
"""

from __future__ import annotations

import numpy as np
from flax import struct

from vbl.engine import Experiment, RunResult, register
from vbl.engine.experiment import PaperRow
from vbl.engine.report import claim
from vbl.envs.collect import CollectParams
from vbl.params import param, section
from vbl.programs.identification import (
    OBJECT,
    TABLE1_ROWS,
    RowSetup,
    check_scenarios,
    claims_markdown,
    identification_cells,
    identification_program,
    point_report,
    row_markdown,
    row_stats,
    slug,
    table1_scenarios,
)
from vbl.programs.paper import TABLE1
from vbl.sysid.params import CVAParams


@struct.dataclass
class Table1Config:
    collect: CollectParams = section(lambda: CollectParams(num_steps=500),
                                     doc="common data-collection setup")
    rows: RowSetup = section(RowSetup, doc="per-row collection changes")
    ident: CVAParams = section(lambda: CVAParams(standardize=False, lag_max=6, lag_rule="paper"),
                               doc="CVA/AIC/lag rule (outputs in y_unit px, not standardised: "
                                   "standardised residuals always give log det R <= 0, so "
                                   "the lag rule would always stop at l = 1)")
    y_unit: float = param(4.0, doc="unit of the identification outputs: log det R < 0 "
                          "means a geometric-mean residual below y_unit px", unit="px", gt=0.0)

    def check(self) -> None:
        check_scenarios(scenarios(self), {slug(k): v for k, v in OBJECT.items()}, self.ident)


def scenarios(c: Table1Config) -> dict[str, CollectParams]:
    return {slug(k): v for k, v in table1_scenarios(c.collect, c.rows).items()}


def make_program(cfg: Table1Config):
    return identification_program(cfg, scenarios, {slug(k): v for k, v in OBJECT.items()})


def checks(final: dict, i: int) -> dict[str, str]:
    """The paper's qualitative claims at sweep point ``i``, each a verdict on the 95 %
    interval of a difference over seeds (:func:`vbl.engine.report.claim`)."""
    v = {(q, k): np.asarray(final[f"{q}_{slug(k)}"][i], np.float64)
         for q in ("l", "logdet_R") for k in TABLE1_ROWS}
    rw, mtb = "random walk", "move to the ball"
    return {
        "goal needs the shortest history (other l − goal l)": "; ".join(
            f"{k}: {claim(v['l', k], v['l', 'goal'], fmt='.2f')}" for k in TABLE1_ROWS[1:]),
        "random walker has the largest log det R (random walk − other)": "; ".join(
            f"{k}: {claim(v['logdet_R', rw], v['logdet_R', k], fmt='.2f')}"
            for k in TABLE1_ROWS if k != rw),
        "move-to-ball error much smaller than random walker (log det R by > 1)": claim(
            v["logdet_R", rw] - 1.0, v["logdet_R", mtb], fmt=".2f"),
    }


def table(res: RunResult, i: int) -> str:
    t = {k: row_stats(res.final, i, k) for k in TABLE1_ROWS}
    cfg = res.config
    lines = [f"Table 1: l, n, log det R, AIC (mean ± 95 % interval over {res.seeds} seeds, one "
             f"data set of N = {cfg.collect.num_steps} per row and seed; l and n also as the mode; "
             f"outputs in {cfg.y_unit:g} px units)", "",
             "| agent | l (ours) | n (ours) | log det R (ours) | AIC (ours) | "
             "l / n / log det R / AIC (paper) |", "|---|---|---|---|---|---|"]
    lines += [row_markdown([k], t[k], TABLE1[k], mode=True) for k in TABLE1_ROWS]
    return "\n".join(lines + claims_markdown(checks(res.final, i)))


def paper_rows(res: RunResult) -> list[PaperRow]:
    return [PaperRow(f"Table 1, {k}: l / n / log det R / AIC" + (
                f" ({', '.join(f'{p}={v}' for p, v in pt.items())})" if pt else ""),
                     " / ".join(str(x) for x in TABLE1[k]), identification_cells(res.final, i, k))
            for i, pt in enumerate(res.points) for k in TABLE1_ROWS]


EXPERIMENT = register(Experiment(
    name="table1_identification",
    description="Table 1: CVA/AIC/lag-rule identification of goal, ball, random walker, "
                "move-to-ball robot (one data set per row and seed)",
    default_config=Table1Config(),
    make_program=make_program,
    quick={},
    seeds=64,
    quick_seeds=16,
    paper_result=True,
    paper={"table1": TABLE1},
    report=point_report(table),
    paper_rows=paper_rows,
    headline=tuple(f"l_{slug(k)}" for k in TABLE1_ROWS),
))

if __name__ == "__main__":
    from vbl.cli import main_for

    main_for(EXPERIMENT)
