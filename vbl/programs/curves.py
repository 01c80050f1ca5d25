"""Learning curves of Q-learning programs in reports: success against training trials,
trials until a success level, and the Learning-from-Easy-Missions verdict."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from flax import struct

from vbl.engine.experiment import RunResult
from vbl.engine.plots import LINESTYLES, band, save_figure
from vbl.params import ParamError, param
from vbl.programs.tabular import curve_metric
from vbl.stats import first_crossing

__all__ = ["CurveReportParams", "lem_label", "trials_to_levels", "lem_verdict",
           "plot_success_vs_trials", "curve_description"]

LEM_PATH = "agent.lem.initial_difficulty"  #: the sweep path that switches LEM off (= the cap)


@struct.dataclass
class CurveReportParams:
    """What a learning-curve report compares."""

    success_levels: tuple = param((0.2, 0.3, 0.5), doc="success rates (the curve's policy, "
                                  "task starts) whose first crossing the report compares in "
                                  "trials (median over seeds, never reached = slowest); the "
                                  "first is drawn in the plot")
    smooth_chunks: int = param(2, doc="a crossing is the first curve point whose mean success "
                               "over the last this many points reaches the level (one "
                               "evaluation has agent.num_envs starts: noisy)", ge=1)

    def check(self) -> None:
        lv = np.asarray(self.success_levels, float)
        if lv.ndim != 1 or lv.size == 0 or np.any((lv <= 0) | (lv > 1)):
            raise ParamError(f"report.success_levels={self.success_levels!r}: one or more "
                             "success rates in (0, 1]")


def lem_label(values: dict, config: Any = None) -> str:
    """"with LEM" when a sweep point starts below the curriculum's cap, "without LEM" when
    it starts at the cap; other sweep points are named by their values."""
    if LEM_PATH in values:
        cap = 1.0 if config is None else float(np.max(config.agent.lem.max_difficulty))
        return "with LEM" if float(values[LEM_PATH]) < cap else "without LEM"
    return ", ".join(f"{k}={v}" for k, v in values.items()) or "run"


def curve_description(res: RunResult) -> tuple[str, str]:
    """(what the curve measures, its axis label) of a Q program's run."""
    ce = float(np.max(res.config.train.curve_epsilon))
    who = "greedy" if ce == 0 else f"near-greedy (epsilon {ce:g})"
    if curve_metric(res.curves) != "eval_success":
        return ("the training success (train.eval_curve is off)",
                "training success (with exploration)")
    d = float(np.max(res.config.train.eval_difficulty))
    return f"the {who} success after each chunk", f"{who} success, d = {d:g}"


def trials_to_levels(res: RunResult, point: int, levels: list[float], window: int
                     ) -> dict[float, tuple[float, int, int]]:
    """Per level: (median trials over seeds until the curve, averaged over ``window``
    points, first reaches it: a seed that never does counts as slowest; seeds reaching it;
    seeds) at sweep point ``point``."""
    success = res.curves[curve_metric(res.curves)][point]
    trials = np.cumsum(res.curves["episodes"][point], axis=0)
    out = {}
    for lv in levels:
        t = first_crossing(success, trials, lv, window)
        out[lv] = (float(np.median(np.where(np.isnan(t), np.inf, t))),
                   int((~np.isnan(t)).sum()), len(t))
    return out


def lem_verdict(t_on: float, t_off: float, n_off: float, n_on: float | None = None) -> str:
    """Does LEM reach a level in fewer trials? ``t_on``, ``t_off``: median trials to the
    level with / without LEM (inf: the median seed never reached it); ``n_off``,
    ``n_on``: trials the runs without / with LEM finished (mean over seeds). A level
    neither arm reaches, or one that only the shorter arm has not reached yet, is "not
    shown" (the run is too short to tell), never "no"."""
    on = f"{t_on:.0f}" if np.isfinite(t_on) else "not reached" + (
        f" in {n_on:.0f}" if n_on is not None else "")
    off = f"{t_off:.0f}" if np.isfinite(t_off) else f"not reached in {n_off:.0f}"
    if not np.isfinite(t_on) and not np.isfinite(t_off):
        return f"**not shown** (neither arm reached it: with LEM {on}, without {off})"
    if not np.isfinite(t_on):
        return f"**no** (with LEM {on}, without {off})"
    if not np.isfinite(t_off) and n_off < t_on:
        return (f"**not shown** (with LEM {on}; without LEM not reached, but it ran only "
                f"{n_off:.0f} trials: run it longer)")
    return f"{'yes' if t_on < t_off else '**no**'} (with LEM {on}, without {off})"


def plot_success_vs_trials(res: RunResult, level: float, path: Path, title: str) -> Path:
    """The success curve of every sweep point (95 % band over seeds) against cumulative
    training trials, the random policy's final success and ``level`` as lines."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    metric = curve_metric(res.curves)
    s_all, e_all = res.curves[metric], res.curves["episodes"]
    for p, values in enumerate(res.points):
        m, lo, hi = band(metric, s_all[p])
        x = np.cumsum(e_all[p].mean(axis=1))
        (line,) = ax.plot(x, m, label=lem_label(values, res.config),
                        ls=LINESTYLES[p % len(LINESTYLES)])
        if s_all[p].shape[1] > 1:
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
    if "random_success" in res.final:
        ax.axhline(float(np.mean(res.final["random_success"])), color="k", ls=":",
                   label="random policy")
    ax.axhline(level, color="gray", lw=0.6, ls="--")
    ax.set(xlabel="training trials (episodes)", ylabel=curve_description(res)[1], ylim=(0, 1),
           title=f"{title} ({res.seeds} seeds, 95% band)")
    ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    return save_figure(fig, path)
