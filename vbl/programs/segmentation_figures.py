"""Figures 8 and 9 of the on-line segmentation, and their report (host side, NumPy).

* :func:`plot_fig9`: success rate (trailing mean over ``window`` trials) and number of
  states per trial, mean and 95 % band over seeds, the changes as dashed lines;
* :func:`plot_fig8`: one learner's final boxes cut by a slice of the normalised feature
  cube, drawn on two of its axes, labelled with their greedy primitive;
* :func:`change_window`, :func:`change_report`, :func:`change_rows`: the success and
  state counts around each change (:func:`vbl.stats.change_windows`) as a markdown table,
  the verdict line and the README rows;
* :func:`report`, :func:`paper_rows`: Figure 9's report section and README rows from a
  run of ``fig9_incremental``.

``final`` dicts hold per-seed arrays: ``trial_success``, ``trial_states`` (seeds, trials);
``box_lo``, ``box_hi`` (seeds, L, D); ``box_active``, ``box_action`` (seeds, L).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vbl.engine.experiment import PaperRow
from vbl.engine.plots import save_figure
from vbl.engine.report import claim, rate_cell, seeds_cell
from vbl.stats import change_windows, mean_ci95, running_mean

__all__ = ["plot_fig9", "plot_fig8", "change_window", "change_report", "change_rows", "report",
           "paper_rows"]

MAX_WINDOW = 50  #: trials per window around a change (narrower when changes are closer)


def _band(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    m, h = mean_ci95(x)
    return m, np.nan_to_num(h)                  # one seed: no band


def plot_fig9(final: dict, changes: tuple[int, ...], out: Path, window: int = 50) -> Path:
    """``out/fig9_success_states.png``: success (trailing ``window``-trial mean) and states."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    succ = running_mean(np.asarray(final["trial_success"], float), window)
    states = np.asarray(final["trial_states"], float)
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(1, succ.shape[-1] + 1)
    ax2 = ax.twinx()
    for a, v, color, label, alpha in (
            (ax, succ, "C0", f"success rate (last {window} trials)", 0.25),
            (ax2, states, "C3", "number of states", 0.2)):
        m, h = _band(v)
        a.plot(x, m, color=color, label=label)
        a.fill_between(x, m - h, m + h, color=color, alpha=alpha)
    ax.set_xlabel("trial")
    ax.set_ylabel("success rate")
    ax.set_ylim(0, 1)
    ax2.set_ylabel("number of states")
    for t in changes:
        ax.axvline(t, color="k", ls="--", lw=0.8)
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="upper left", fontsize=8)
    ax.set_title(f"Figure 9: on-line segmentation, mean and 95% band over {succ.shape[0]} seeds")
    return save_figure(fig, out / "fig9_success_states.png")


def plot_fig8(final: dict, scale: tuple[float, float], labels: tuple[str, ...], out: Path,
              axes: tuple[int, int] = (0, 2), seed: int = 0) -> Path:
    """``out/fig8_state_space.png``: the boxes of learner ``seed`` cut by the slice where
    every other normalised feature is 0.5 (Section-2 features: x2 = x4 = 0 px, x5 = 0,
    both objects visible), drawn on ``axes`` (default ball size x1, goal size x3) scaled
    to px by ``scale``; ``labels`` the primitive names."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    lo, hi = np.asarray(final["box_lo"])[seed], np.asarray(final["box_hi"])[seed]
    act = np.asarray(final["box_active"])[seed] > 0.5
    acts = np.asarray(final["box_action"])[seed].astype(int)
    (i0, i1), (s0, s1) = axes, scale
    other = [d for d in range(lo.shape[1]) if d not in axes]
    up = (0.5 < hi[:, other]) | (hi[:, other] >= 1.0)          # as leaf_of
    cut = act & np.all((lo[:, other] <= 0.5) & up, axis=1)
    fig, ax = plt.subplots(figsize=(5.5, 5))
    cmap = plt.get_cmap("tab10")
    for i in np.flatnonzero(cut):
        x0, y0 = lo[i, i0] * s0, lo[i, i1] * s1
        w, h = (hi[i, i0] - lo[i, i0]) * s0, (hi[i, i1] - lo[i, i1]) * s1
        ax.add_patch(Rectangle((x0, y0), w, h, fc=cmap(acts[i] % 10), alpha=0.35, ec="k"))
        ax.text(x0 + w / 2, y0 + h / 2, labels[acts[i]], ha="center", va="center", fontsize=7)
    ax.set_xlim(0, s0)
    ax.set_ylim(0, s1)
    ax.set_xlabel(f"ball size x{i0 + 1} [px]" if axes == (0, 2) else f"x{i0 + 1} [px]")
    ax.set_ylabel(f"goal size x{i1 + 1} [px]" if axes == (0, 2) else f"x{i1 + 1} [px]")
    ax.set_title(f"Figure 8: final boxes (seed {seed}), {int(act.sum())} states in all")
    return save_figure(fig, out / "fig8_state_space.png")


def change_window(changes: tuple[int, int], trials: int) -> int:
    """Trials per window: ``MAX_WINDOW``, or half the shortest span between the start, the
    changes and the last trial when that is narrower (at least 1)."""
    c1, c2 = changes
    return max(1, min(MAX_WINDOW, min(c1, c2 - c1, trials - c2) // 2))


def change_report(success: Any, states: Any, changes: tuple[int, ...], window: int
                  ) -> list[str]:
    """Markdown lines: the table of :func:`vbl.stats.change_windows` (success mean ± 95 %
    CI over seeds, mean states) and the verdict (drops, recovers, states grow)."""
    cell = lambda v: rate_cell(v)  # noqa: E731
    md = ["| change | before | right after | end of recovery window | states before -> "
          f"{window} trials after -> end of recovery window |", "|---|---|---|---|---|"]
    verdict = []
    for i, cw in enumerate(change_windows(success, states, changes, window)):
        r, st = cw["rates"], cw["states"]
        (a0, a1), (b0, b1), (e0, e1) = cw["spans"]
        md.append(f"| {i + 1} (trial {cw['change']}) | {cell(r[:, 0])} ({a0}-{a1}) | "
                  f"{cell(r[:, 1])} ({b0}-{b1}) | {cell(r[:, 2])} ({e0}-{e1}) | "
                  f"{st[:, 0].mean():.1f} -> {st[:, 1].mean():.1f} -> {st[:, 2].mean():.1f} |")
        verdict.append((claim(r[:, 0], r[:, 1], paired=True),
                        claim(r[:, 2], r[:, 1], paired=True),
                        claim(st[:, 2], st[:, 0], paired=True)))
    md += ["", "What must hold, per change (paired over seeds, 95 % intervals): success drops "
           "after the change (before − right after > 0), rises again in the recovery window "
           "(end − right after > 0), and the number of states grows (end − before > 0).", "",
           "| change | drops | recovers | states grow |", "|---|---|---|---|"]
    return md + [f"| {i + 1} | {v[0]} | {v[1]} | {v[2]} |" for i, v in enumerate(verdict)]


def change_rows(success: Any, states: Any, changes: tuple[int, ...], window: int
                ) -> list[PaperRow]:
    """One README row per change: success before / after / at the end of recovery."""
    return [PaperRow(f"Figure 9, ball-size change {i + 1} (trial {cw['change']}): success in "
                     f"{window}-trial windows before / after / at the end of recovery",
                     "drops, then recovers (no number)",
                     " / ".join(rate_cell(cw["rates"][:, j]) for j in range(3)))
            for i, cw in enumerate(change_windows(success, states, changes, window))]


def _finished(res: Any) -> tuple[dict, int, tuple[int, int], int]:
    """First sweep point's per-seed finals cut to the trials every seed finished; the
    changes; the window."""
    fin = {k: np.asarray(v)[0] for k, v in res.final.items()}
    n = int(min(fin["trials_done"].min(), fin["trial_success"].shape[1]))
    fin["trial_success"], fin["trial_states"] = (fin[k][:, :n] for k in ("trial_success",
                                                                         "trial_states"))
    ch = res.config.change
    changes = (int(ch.change_trial_1), int(ch.change_trial_2))
    return fin, n, changes, change_window(changes, n)


def report(res: Any) -> Any:
    """Figure 9's report section: the figures, the change table and the final policies.
    ``res.config`` has Figure 9's sections (``env``, ``features``, ``change``, ``train``,
    ``grid``)."""
    from vbl.engine.experiment import ReportSection
    from vbl.spaces.grid import NUM_GRID_STATES
    from vbl.world.robots import action_labels

    cfg, out = res.config, Path(res.out_dir)
    fin, n, changes, w = _finished(res)
    fp, ch, tr = cfg.features, cfg.change, cfg.train
    figures = (plot_fig9(fin, changes, out),
               plot_fig8(fin, (fp.ball_size_max, fp.goal_size_max), action_labels("two_motor"),
                         out))
    cell = lambda k: rate_cell(fin[k])  # noqa: E731
    md = [f"On-line segmentation, {fin['trial_success'].shape[0]} seeds, {n} trials (finished "
          f"by every seed of {tr.num_trials}), ball radius {ch.radius_0} -> {ch.radius_1} m "
          f"(trial {ch.change_trial_1}) -> {ch.radius_2} m (trial {ch.change_trial_2}). "
          f"Success rate over {w}-trial windows (training episodes, Boltzmann exploration "
          "included), mean ± 95% CI over seeds:", ""]
    md += change_report(fin["trial_success"], fin["trial_states"], changes, w) + [""]
    gs = fin["greedy_success"]
    line = (f"Greedy policy on {tr.eval_episodes} fresh starts per seed (start difficulty "
            f"{cfg.baseline.train.eval_difficulty}, final ball, {cfg.env.max_steps}-primitive "
            f"limit): {cell('greedy_success')} with {seeds_cell(fin['states'], fmt='.1f')} "
            f"states ({fin['value_splits'].mean():.1f} of {fin['splits'].mean():.1f} splits "
            "per seed by the value criterion); the learner's own Boltzmann behaviour, frozen, "
            f"{cell('boltzmann_success')}; uniformly random primitives on the same starts "
            f"{cell('random_success')}")
    if "steer_success" in fin:
        line += ("; the hand-written steering policy (train.steer_band, what is achievable "
                 f"with this ball) {cell('steer_success')}")
    if "grid_success" in fin:
        g = cfg.baseline
        line += (f"; the grid baseline (grid_shooting's learner, {NUM_GRID_STATES} states, "
                 f"trained on the final ball, same start difficulty and limit) "
                 f"{cell('grid_success')}. Above the grid's success: "
                 f"{claim(gs, fin['grid_success'])}, with fewer states: "
                 f"{'yes' if fin['states'].mean() < NUM_GRID_STATES else '**no**'}. "
                 "Experience: the grid learner "
                 f"{fin['grid_trials'].mean():,.0f} trials ({fin['grid_primitives'].mean():,.0f}"
                 f" primitives, {g.agent.num_envs} envs x {g.train.num_chunks} chunks x "
                 f"{g.agent.chunk_steps} learner steps), the on-line learner "
                 f"{fin['trials_done'].mean():,.0f} trials ({fin['primitives_done'].mean():,.0f}"
                 " primitives), means over seeds.")
    else:
        line += ("; beating the grid baseline at equal experience: not measured at this scale "
                 "(train.grid_baseline is off, as under --quick; the full run measures it).")
    return ReportSection(markdown="\n".join(md + [line]), figures=figures)


def paper_rows(res: Any) -> list[PaperRow]:
    """README rows: each change, the final greedy policy, the grid baseline."""
    fin, _, changes, w = _finished(res)
    rows = change_rows(fin["trial_success"], fin["trial_states"], changes, w)
    rows.append(PaperRow("Figure 9, final greedy policy: success / states",
                         "less learning time than the off-line method (no number)",
                         f"{rate_cell(fin['greedy_success'])} / "
                         f"{seeds_cell(fin['states'], fmt='.1f')}"))
    if "grid_success" in fin:
        rows.append(PaperRow("Figure 9, grid baseline (319 states), same experience: success",
                             "-", rate_cell(fin["grid_success"])))
    return rows
