"""Grid baseline: Q-learning to shoot on the hand-designed 319-state grid, with and without
Learning from Easy Missions (the earlier work the paper compares against, Figure 5's grid).

Each learner trains one Q-table (319 states x 9 primitives, one action = repeat a
primitive until the grid state changes, at least ``MIN_REPEATS`` primitives) with
``agent.num_envs`` parallel robots. The task is shooting from starts at
``TASK_DIFFICULTY`` (0.1 by default; 1 = fully random starts, out of reach of this
baseline in the run length: numbers in docs/agents.md). After every chunk the greedy
policy is evaluated on fresh starts at that difficulty: the ``success_rate`` curve against
training trials (cumulative episodes). The default sweep compares LEM off
(``agent.lem.initial_difficulty = max_difficulty``: every episode starts at the task
difficulty, exactly as with the curriculum switched off, but in the same compiled
program) with LEM on (episodes start easy, difficulty 0, and move out to the task
difficulty when Q stops changing and the training episodes succeed). ``final``: greedy and
random policy success on fresh starts at the task difficulty. For fully random starts:
``--set train.eval_difficulty=1 --set agent.lem.max_difficulty=1 --sweep
agent.lem.initial_difficulty=1,0``.

Run: ``vbl run grid_shooting [--quick]`` or ``python experiments/grid_shooting.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from flax import struct

from vbl.agents import QRunnerParams
from vbl.agents.programs import QTrainParams, make_q_program, trials_to_level
from vbl.engine import Experiment, ReportSection, RunResult, register
from vbl.envs.shooting import ShootingEnv, ShootingParams
from vbl.params import param, section
from vbl.spaces.grid import NUM_GRID_STATES, GridParams, grid_state

ENV = ShootingEnv()


@struct.dataclass
class ReportParams:
    success_level: float = param(0.1, doc="success rate (greedy, task starts) whose first "
                                 "crossing the report compares in trials", gt=0.0, le=1.0)


TASK_DIFFICULTY = 0.1
"""Start difficulty of the reported task (evaluation, and the cap of the curriculum).
From fully random starts (1) the ball is in view at only ~20 % of starts and the goal at
~24 %. A hand-written table on the 319 grid states scores 0.70 there within 100 s
(random 0.004), but Q-learning does not find or even keep such a policy: started from that
table it unlearns it within 400 learner steps (greedy 0.74 -> 0.02), and learned greedy
and near-greedy policies stay at 0.00-0.05 at difficulty 1 (docs/agents.md, "Fully random
starts"). So the default task stays at 0.1, where greedy beat random at 30 s."""


MIN_REPEATS = 3  #: primitives per macro action at least (0.3 s)

MAX_STEPS = 300
"""Time limit of this experiment's episodes, primitives (30 s, the env's default). From fully
random starts that is too short even for scripted policies (0.07-0.23); with 100 s
(``--set env.max_steps=1000``) they score 0.70 (a hand-written table on the 319 grid
states) to 0.91 (docs/agents.md, "Fully random starts"). The learned grid policy does not
reach difficulty 1 with either limit, and at the reported difficulty 0.1 the random policy
already scores 0.13-0.17 with 100 s, so the default stays 30 s, where the full-scale
numbers in docs/agents.md were measured."""

EVAL_STEPS = 400
"""Cap on (macro) actions per evaluation episode: above ``MAX_STEPS / MIN_REPEATS`` (100), so
the env's time limit, not the cap, ends an unfinished evaluation episode."""


def _agent() -> QRunnerParams:
    """Defaults of this experiment (the library's otherwise):

    * discount 0.98 per primitive (0.8 would make a goal more than ~3 s away worth
      < 0.8**30 = 1e-3);
    * macro actions run at least ``MIN_REPEATS`` primitives: with one, a turn in place
      flipped the goal's orientation category every primitive and the greedy policy cycled
      between two look-alike states until the time limit (measured);
    * LEM: the curriculum runs from difficulty 0 to the task's ``TASK_DIFFICULTY`` (LEM off =
      ``initial_difficulty = max_difficulty``: every episode at the task difficulty);
      convergence = mean |change| of Q over 100 learner steps below 0.01, and the training
      episodes of that window succeeded at >= 80 % (without the success gate the
      curriculum moves on whenever no reward arrives, as Q then stops changing too);
      raises in steps of 0.05.
    """
    a = QRunnerParams()
    agent = a.agent.replace(discount=0.98)
    macro = a.macro.replace(min_repeats=MIN_REPEATS)
    lem = a.lem.replace(statistic="mean", window=100, threshold=0.01, step=0.05,
                        success_level=0.8, max_difficulty=TASK_DIFFICULTY)
    return a.replace(agent=agent, macro=macro, lem=lem, num_envs=64, chunk_steps=100)


def _grid() -> GridParams:
    """Orientation cut at +-0.3 (library: +-0.1): measured x5 quartiles are about +-0.13
    both at easy starts (robot on the goal axis: truly frontal) and at random ones, so
    +-0.1 split frontal views into left/right by noise of the projected post heights."""
    return GridParams(orient_lower=-0.3, orient_upper=0.3)


def _env() -> ShootingParams:
    """The env's defaults with the time limit ``MAX_STEPS`` (30 s)."""
    return ShootingParams(max_steps=MAX_STEPS)


def _train() -> QTrainParams:
    return QTrainParams(eval_difficulty=TASK_DIFFICULTY, eval_steps=EVAL_STEPS)


@struct.dataclass
class GridShootingConfig:
    env: ShootingParams = section(_env, doc="shooting task (Section 2), 30 s time limit")
    grid: GridParams = section(_grid, doc="grid boundaries (319 states)")
    agent: QRunnerParams = section(_agent, doc="Q-learning, macro actions, LEM")
    train: QTrainParams = section(_train, doc="run length and evaluation")
    report: ReportParams = section(ReportParams, doc="report settings")


def make_program(cfg: GridShootingConfig):
    return make_q_program(ENV, lambda obs, c: grid_state(obs, c.grid), cfg,
                          num_states=NUM_GRID_STATES)


LEM_PATH = "agent.lem.initial_difficulty"


def _label(values: dict, config=None) -> str:
    """"with LEM" when the sweep point starts below the curriculum's cap, else "without"."""
    if LEM_PATH in values:
        cap = 1.0 if config is None else float(np.max(config.agent.lem.max_difficulty))
        return "with LEM" if float(values[LEM_PATH]) < cap else "without LEM"
    return ", ".join(f"{k}={v}" for k, v in values.items()) or "run"


def _ci(x: np.ndarray) -> tuple[float, float]:
    from vbl.engine.results import t_quantile_975

    x = np.asarray(x, float)
    h = t_quantile_975(len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x)) if len(x) > 1 else 0.0
    return float(x.mean()), float(h)


def plot(res: RunResult, level: float) -> Path:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from vbl.engine.results import t_quantile_975

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    s_all, e_all = res.curves["success_rate"], res.curves["episodes"]
    for p, values in enumerate(res.points):
        y, x = s_all[p], np.cumsum(e_all[p].mean(axis=1))
        m = y.mean(axis=1)
        (line,) = ax.plot(x, m, label=_label(values, res.config))
        if y.shape[1] > 1:
            h = t_quantile_975(y.shape[1] - 1) * y.std(axis=1, ddof=1) / np.sqrt(y.shape[1])
            ax.fill_between(x, m - h, m + h, color=line.get_color(), alpha=0.2, lw=0)
    if "random_success" in res.final:
        ax.axhline(float(np.mean(res.final["random_success"])), color="k", ls=":",
                   label="random policy")
    ax.axhline(level, color="gray", lw=0.6, ls="--")
    ax.set(xlabel="training trials (episodes)", ylabel="greedy success, random starts",
           ylim=(0, 1), title=f"Grid Q-learning shooting ({res.seeds} seeds, 95% band)")
    ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(res.out_dir) / "grid_shooting_lem.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def report(res: RunResult) -> ReportSection:
    level = float(res.config.report.success_level)
    fig = plot(res, level)
    curve = ("the greedy success after each chunk" if res.config.train.eval_curve else
             "the training success (train.eval_curve is off)")
    md = [f"Greedy policy on fresh starts at start difficulty "
          f"{res.config.train.eval_difficulty} (1: fully random), {res.seeds} seeds, "
          f"mean ± 95% CI; {NUM_GRID_STATES} grid states. Trials = training episodes until "
          f"{curve} first reaches {level:.0%} (median over the seeds that reach it).", "",
          f"Near-greedy: a uniform action with probability {res.config.train.eval_epsilon} "
          "(breaks cycles between aliased grid states).", "",
          "| policy | greedy success | near-greedy success | trials to reach "
          f"{level:.0%} | seeds reaching it | training trials |", "|---|---|---|---|---|---|"]
    rnd, greedy, near, reach = [], {}, {}, {}
    for p, values in enumerate(res.points):
        g = _ci(res.final["greedy_success"][p])
        ng = (_ci(res.final["near_greedy_success"][p]) if "near_greedy_success" in res.final
              else (float("nan"), 0.0))
        rnd.append(res.final["random_success"][p])
        eps = res.curves["episodes"][p]
        t = trials_to_level(res.curves["success_rate"][p], eps, level)
        ok = ~np.isnan(t)
        med = f"{np.median(t[ok]):.0f}" if ok.any() else "not reached"
        greedy[_label(values, res.config)] = g
        near[_label(values, res.config)] = ng
        reach[_label(values, res.config)] = (float(np.median(t[ok])) if ok.any() else np.inf,
                                 float(eps.sum(axis=0).mean()))
        md.append(f"| {_label(values, res.config)} | {g[0]:.3f} ± {g[1]:.3f} | "
                  f"{ng[0]:.3f} ± {ng[1]:.3f} | {med} | "
                  f"{int(ok.sum())}/{len(t)} | {reach[_label(values, res.config)][1]:.0f} |")
    # the random policy's evaluation uses the same keys at every sweep point (common random
    # numbers), so average over points per seed rather than pooling duplicates
    r = _ci(np.mean(rnd, axis=0))
    md.append(f"| random policy | {r[0]:.3f} ± {r[1]:.3f} | | | | |")
    md += ["", "What must hold (the paper gives no number for this baseline):", ""]
    for name, table in (("greedy", greedy), ("near-greedy", near)):
        best = max(table.values(), key=lambda v: v[0])
        above = best[0] - best[1] > r[0] + r[1]
        md.append(f"* the {name} policy shoots above the random policy (95% intervals apart): "
                  f"{'yes' if above else '**no**'} (best {best[0]:.3f} vs random {r[0]:.3f});")
    if {"with LEM", "without LEM"} <= set(reach):
        (t_on, _), (t_off, n_off) = reach["with LEM"], reach["without LEM"]
        fewer = t_on < min(t_off, n_off) if np.isfinite(t_on) else False
        md.append(f"* LEM reaches {level:.0%} in fewer trials: {'yes' if fewer else '**no**'}"
                  f" (with LEM {t_on:.0f}, without {t_off:.0f} of {n_off:.0f} trials run).")
    return ReportSection("\n".join(md), (fig,))


EXPERIMENT = register(Experiment(
    name="grid_shooting",
    description="grid-baseline Q-learning shooting (319 states), with and without LEM",
    default_config=GridShootingConfig(),
    make_program=make_program,
    sweep={LEM_PATH: [TASK_DIFFICULTY, 0.0]},
    # --quick: a smoke run (one evaluation compiled, not two): the curve is the training
    # success, the final evaluation is as in the full run but on 32 starts
    quick={"train.num_chunks": 4, "agent.num_envs": 16, "agent.chunk_steps": 50,
           "train.eval_curve": False, "train.final_eval_rounds": 1},
    seeds=8,
    quick_seeds=2,
    paper_result=True,
    cost=60.0,  # s of a cold --quick run on 2 cores (compile-dominated)
    paper={"baseline": "the earlier work's hand-designed grid (grid lines of Figure 5)"},
    report=report,
))

if __name__ == "__main__":
    from vbl.engine import main_for

    main_for(EXPERIMENT)
