"""Report sections and figures of the PPO comparator (:mod:`vbl.programs.ppo_program`).

* :func:`shoot_pass_section`: the two-robot task (Table 2's): one row per task and input,
  PPO without and with the curriculum beside the tabular learner and the paper, and
  whether PPO on current features, frame stacks or CVA states shows the paper's CVA
  advantage (Welch 95 % intervals over seeds);
* :func:`shooting_section`: the shooting task of Section 2 beside the grid baseline.

Success rates are in % (``final["greedy_success_rate"]`` x 100); every interval comes
from :mod:`vbl.stats` (one seed: the mean alone, no interval).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from vbl.agents.ppo_inputs import INPUTS
from vbl.engine.experiment import PaperRow, ReportSection, RunResult
from vbl.engine.plots import band, save_figure
from vbl.engine.rebuild import sibling_result
from vbl.engine.report import rate_cell, seeds_cell
from vbl.programs.curves import LEM_PATH
from vbl.programs.paper import TABLE2
from vbl.stats import mean_ci95, seeds_to_resolve, welch_ci95

__all__ = ["TASKS", "point_keys", "diff_verdict", "shoot_pass_section", "shooting_section",
           "tabular_cells", "grid_cells", "shoot_pass_rows", "shooting_rows",
           "plot_success_vs_steps", "plot_two_robot_curves"]

TASKS = ("shoot", "pass")  #: two-robot tasks, in report order (``env.task_pass`` False, True)
PCT = (0.0, 100.0)  #: range of a success rate in %
INPUT_LABELS = {"current": "current features", "stack": "last 3 frames",
                "cva": "CVA state"}  #: row labels of the inputs
Key = tuple[str, str, bool]  #: (task, input, curriculum on) of a two-robot sweep point


def _value(res: RunResult, point: dict, path: str) -> Any:
    """A sweep point's value of ``path``, else the run's config value."""
    if path in point:
        return point[path]
    obj = res.config
    for name in path.split("."):
        obj = getattr(obj, name)
    return obj


def point_keys(res: RunResult) -> list[Key]:
    """(task, input, curriculum on) of every sweep point of a ``ppo_comparator`` run."""
    return [("pass" if bool(_value(res, pt, "env.task_pass")) else "shoot",
             INPUTS[int(_value(res, pt, "inputs.index"))],
             bool(_value(res, pt, "ppo.curriculum.enabled"))) for pt in res.points]


def _pct(res: RunResult) -> np.ndarray:
    return 100 * np.asarray(res.final["greedy_success_rate"], np.float64)  # (points, seeds)


def _steps(res: RunResult) -> int:
    """Training env steps per learner at the end of the run."""
    return int(np.nanmax(np.asarray(res.curves["env_steps"])[:, -1]))


def diff_verdict(a: Any, b: Any, paper: float | None = None) -> str:
    """``"d ± h (verdict)"``: mean(a) − mean(b) with Welch's 95 % half-width; the verdict
    is "above 0", "below 0" or "spans 0", and with ``paper`` (the paper's difference)
    whether the interval holds it."""
    d, h = welch_ci95(a, b)
    if h != h:
        return f"{d:+.1f} (one seed: no interval)"
    lo, hi = d - h, d + h
    side = "above 0" if lo > 0 else "below 0" if hi < 0 else "spans 0"
    n = min(np.size(a), np.size(b))
    need = seeds_to_resolve(d, h, n) if side == "spans 0" else None
    if need:
        side += f": not resolved at {n} seeds, about {need} would resolve it"
    if paper is not None:
        where = "inside" if lo <= paper <= hi else "above" if paper > hi else "below"
        side += f"; paper's {paper:+.1f} {where} it"
    return f"{d:+.1f} ± {h:.1f} ({side})"


def _advantage(by: dict[Key, np.ndarray], task: str, cur: bool, paper: float) -> str:
    """Per input (CVA state, frame stack): does PPO (curriculum ``cur``) show the paper's
    CVA advantage on ``task``? "yes" (interval above 0; of the paper's size when it holds
    ``paper``), "no, reversed" (below 0), "no, none of the paper's size" (spans 0, below
    ``paper``) or "not resolved" (spans 0 and holds ``paper``)."""
    now = by.get((task, "current", cur))
    out = []
    for key, name in (("cva", "CVA"), ("stack", "stack")):
        if now is None or (task, key, cur) not in by:
            continue
        d, h = welch_ci95(by[task, key, cur], now)
        if h != h:
            v = "no interval"
        elif d - h > 0:
            v = ("yes, the paper's size" if d + h >= paper else "yes, smaller than the "
                 "paper's") if d - h <= paper else "yes, larger than the paper's"
        else:
            v = ("no, reversed" if d + h < 0 else "no, none of the paper's size"
                 if d + h < paper else "not resolved")
        out.append(f"{name}: {v}")
    return "; ".join(out) or "not run"


def tabular_cells(res: RunResult) -> dict[str, dict[str, str]]:
    """``{task: {input: "mean ± half-width"}}`` greedy success % of the tabular learner
    (Table 2's defaults) from the ``table2_shoot_pass`` run folder beside ``res``'s (as
    ``vbl reproduce`` writes them); {} without one."""
    t2 = sibling_result(res, "table2_shoot_pass")
    if t2 is None or "greedy_success" not in t2.final:
        return {}
    out: dict[str, dict[str, str]] = {}
    for i, pt in enumerate(t2.points):
        if bool(_value(t2, pt, "ball_velocity")):  # the velocity control, not a default
            continue
        task = "pass" if bool(_value(t2, pt, "env.task_pass")) else "shoot"
        inp = "cva" if bool(_value(t2, pt, "cva.use_cva")) else "current"
        out.setdefault(task, {})[inp] = rate_cell(t2.final["greedy_success"][i], 100.0,
                                                  ".1f")
    return out


def grid_cells(res: RunResult) -> dict[bool, tuple[str, str]]:
    """``{lem on: (greedy %, near-greedy %)}`` of the grid baseline from the
    ``grid_shooting`` run folder beside ``res``'s; {} without one."""
    g = sibling_result(res, "grid_shooting")
    if g is None or "greedy_success" not in g.final:
        return {}
    out = {}
    for i, pt in enumerate(g.points):
        on = float(_value(g, pt, LEM_PATH)) < float(g.config.agent.lem.max_difficulty)
        out[on] = tuple(rate_cell(g.final[k][i], 100.0, ".1f")
                        for k in ("greedy_success", "near_greedy_success"))
    return out


def shoot_pass_section(res: RunResult, paper: Mapping[str, Mapping[str, float]]
                       ) -> ReportSection:
    """The two-robot comparison beside the tabular learner (:func:`tabular_cells`) and the
    paper's % (``paper[task][input]``, :data:`vbl.programs.paper.TABLE2`)."""
    tabular = tabular_cells(res)
    keys, sr = point_keys(res), _pct(res)
    by = dict(zip(keys, sr, strict=True))
    cur_label = {False: "off", True: "on"}
    arms = sorted({k[2] for k in keys})  # curriculum settings the run has
    rows = ["| task | input | " + " | ".join(f"PPO greedy %, curriculum {cur_label[c]}"
                                           for c in arms)
            + " | tabular Q %, Table 2 defaults (table2_shoot_pass beside this run) | paper % |",
            "|---|---|" + "---|" * len(arms) + "---|---|"]
    for task in TASKS:
        for inp in INPUTS:
            if not any((task, inp, c) in by for c in arms):
                continue
            ppo = [seeds_cell(by[task, inp, c], fmt=".1f", bounds=PCT) if (task, inp, c) in by
                   else "not run" for c in arms]
            tab = tabular.get(task, {}).get(inp, "-" if tabular else "- (no run beside)")
            rows.append(f"| {task} | {inp} | {' | '.join(ppo)} | {tab} | "
                        f"{paper[task].get(inp, '- (none)')} |")
    adv = ["| task | curriculum | PPO CVA − current | PPO stack − current | PPO shows the "
           "paper's CVA advantage? | PPO greedy % vs the paper's CVA learner |",
           "|---|---|---|---|---|---|"]
    for task in TASKS:
        gap = paper[task]["cva"] - paper[task]["current"]
        for cur in arms:
            now = by.get((task, "current", cur))
            if now is None:
                continue
            diffs = [diff_verdict(by[task, k, cur], now, gap) if (task, k, cur) in by
                     else "not run" for k in ("cva", "stack")]
            level = "; ".join(_versus(by[task, k, cur], paper[task]["cva"], k)
                              for k in INPUTS if (task, k, cur) in by)
            adv.append(f"| {task} | {cur_label[cur]} | {diffs[0]} | {diffs[1]} | "
                       f"{_advantage(by, task, cur, gap)} | {level} |")
    on_off = [f"* {task}: " + "; ".join(
        f"{inp} {diff_verdict(by[task, inp, True], by[task, inp, False])}" for inp in INPUTS
        if (task, inp, True) in by and (task, inp, False) in by) + " points"
        for task in TASKS if any((task, i, c) in by for i in INPUTS for c in (False, True))]
    fig = plot_two_robot_curves(res.curves, keys, res.out_dir / "ppo_success_vs_steps.png",
                                "PPO, two-robot task")
    paper_gap = ", ".join(f"{t} {paper[t]['cva'] - paper[t]['current']:+.1f}" for t in TASKS)
    md = (f"brax PPO (categorical policy) on Table 2's task, {res.seeds} seeds, "
          f"{_steps(res):,} training primitives per learner; greedy = deterministic policy "
          "at the full start distribution (start difficulty 1), first episode from each of "
          "the final evaluation's fresh starts; mean ± 95 % CI over seeds. The tabular "
          "learner of Table 2 runs without a curriculum, as PPO's curriculum-off runs."
          "\n\n" + "\n".join(rows)
          + "\n\nDoes PPO show the paper's CVA advantage (paper, CVA − current: "
          f"{paper_gap} points)? Differences of means with Welch 95 % intervals; an "
          "input shows the advantage when its interval is above 0, of the paper's size "
          "when it also holds the paper's difference. Last column: PPO's greedy success "
          "on each input against the paper's CVA learner's (one-sample 95 % interval "
          "above, below or holding it).\n\n" + "\n".join(adv)
          + ("\n\nCurriculum on − off (Welch 95 %):\n\n" + "\n".join(on_off)
             if any(k[2] for k in keys) else ""))
    return ReportSection(markdown=md, figures=(fig, *res.figures))


def shoot_pass_rows(res: RunResult) -> list[PaperRow]:
    """``vbl report`` rows of a ``ppo_comparator`` run: greedy success % per task and input
    (not in the paper: its CVA learner's % stands beside the CVA row)."""
    rows = []
    for (task, inp, cur), sr in zip(point_keys(res), _pct(res), strict=True):
        what = "passing" if task == "pass" else "shooting"
        paper = TABLE2[task].get(inp)
        rows.append(PaperRow(
            f"PPO (not in the paper), {what}, {INPUT_LABELS[inp]}"
            f"{', curriculum' if cur else ''}: greedy success %",
            f"{paper} (tabular)" if paper is not None else "-", seeds_cell(sr, fmt=".1f",
                                                                        bounds=PCT)))
    return rows


def shooting_rows(res: RunResult) -> list[PaperRow]:
    """``vbl report`` rows of a ``ppo_shooting`` run: greedy success % per curriculum arm."""
    sr = _pct(res)
    return [PaperRow("PPO (not in the paper), Section 2 shooting, "
                     f"{'with' if bool(_value(res, pt, 'ppo.curriculum.enabled')) else 'without'}"
                     " curriculum: greedy success %", "-", seeds_cell(sr[i], fmt=".1f", bounds=PCT))
            for i, pt in enumerate(res.points)]


def _versus(x: np.ndarray, level: float, name: str) -> str:
    m, h = mean_ci95(x)
    if h != h:
        return f"{name} {m:.1f}"
    return f"{name} {'above' if m - h > level else 'below' if m + h < level else 'inside'}"


def shooting_section(res: RunResult) -> ReportSection:
    """The shooting task beside the grid baseline without / with LEM
    (:func:`grid_cells`)."""
    grid = grid_cells(res)
    sr, rows = _pct(res), ["| curriculum | PPO greedy % | grid Q greedy % (LEM as the "
                           "row) | grid Q near-greedy % |", "|---|---|---|---|"]
    labels = []
    for i, pt in enumerate(res.points):
        on = bool(_value(res, pt, "ppo.curriculum.enabled"))
        labels.append("with curriculum" if on else "without curriculum")
        g = grid.get(on, ("- (no run beside)",) * 2)
        rows.append(f"| {'on' if on else 'off'} | {seeds_cell(sr[i], fmt='.1f', bounds=PCT)} | "
                    f"{g[0]} | {g[1]} |")
    fig = plot_success_vs_steps(res.curves, labels, res.out_dir / "ppo_success_vs_steps.png",
                                "PPO, shooting (Section 2)")
    md = (f"brax PPO on the shooting task from fully random starts (100 s limit), "
          f"{res.seeds} seeds, {_steps(res):,} training primitives per learner (grid "
          "baseline: ~3 M); mean ± 95 % CI.\n\n" + "\n".join(rows))
    return ReportSection(markdown=md, figures=(fig, *res.figures))


def _axes(n: int):
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, n, figsize=(5.2 * n if n > 1 else 6.4, 4.0), squeeze=False)
    return fig, axes[0]


def _line(ax, steps: np.ndarray, sr: np.ndarray, **kw) -> None:
    """Mean over seeds of ``sr`` (chunks, seeds) against ``steps`` with its 95 % band."""
    x = steps.mean(axis=1)  # env steps at the end of each chunk
    m, lo, hi = band("success_rate", sr)
    (line,) = ax.plot(x, m, **kw)
    if sr.shape[1] > 1:
        ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.15, lw=0)


def _finish(fig, axes, path: Path) -> Path:
    for ax in axes:
        ax.set(xlabel="training env steps (primitives) per learner", ylabel="success rate",
               ylim=(0, 1))
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    return save_figure(fig, path)


def plot_success_vs_steps(curves: dict, labels: list[str], path: Path, title: str) -> Path:
    """``success_rate`` (mean over seeds, 95 % band) against training env steps, one line
    per sweep point; ``curves[metric]`` is (points, chunks, seeds)."""
    steps, sr = np.asarray(curves["env_steps"]), np.asarray(curves["success_rate"])
    fig, axes = _axes(1)
    for i, label in enumerate(labels):
        _line(axes[0], steps[i], sr[i], label=label)
    axes[0].set_title(f"{title} ({sr.shape[2]} seeds, 95% band)")
    return _finish(fig, axes, path)


def plot_two_robot_curves(curves: dict, keys: list[Key], path: Path, title: str) -> Path:
    """The two-robot ``success_rate`` against training env steps: a panel per task, a
    colour per input, dashed with the curriculum; ``keys[i]`` = (task, input, curriculum)
    of sweep point i; ``curves[metric]`` is (points, chunks, seeds)."""
    steps, sr = np.asarray(curves["env_steps"]), np.asarray(curves["success_rate"])
    tasks = [t for t in TASKS if any(k[0] == t for k in keys)]
    colours = dict(zip(INPUTS, ("C0", "C1", "C2"), strict=True))
    fig, axes = _axes(len(tasks))
    for ax, task in zip(axes, tasks, strict=True):
        for i, (t, inp, cur) in enumerate(keys):
            if t == task:
                _line(ax, steps[i], sr[i], color=colours[inp], ls="--" if cur else "-",
                      label=f"{inp}{', curriculum' if cur else ''}")
        ax.set_title(task)
    fig.suptitle(f"{title} ({sr.shape[2]} seeds, mean and 95% band; evaluation at start "
                 "difficulty 1)", fontsize="medium")
    return _finish(fig, axes, path)
