"""Learning-curve figures (matplotlib Agg): one line per sweep point, 95% band over seeds."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from vbl.params import ParamError
from vbl.stats import mean_ci95

__all__ = ["point_label", "plot_curves", "plot_names", "plot_sweep", "is_rate", "band", "pyplot",
           "save_figure", "FIGURE_DPI"]

FIGURE_DPI = 120  #: dots per inch of every figure vbl writes
LINESTYLES = ("-", "--", ":", "-.")  #: one per sweep point (cycled): coinciding lines stay visible


def is_rate(metric: str) -> bool:
    """A metric that is a fraction in [0, 1] (its name says so: ``*rate*``, ``*success*``)."""
    return "rate" in metric or "success" in metric


def band(metric: str, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, lower, upper) over seeds of ``values`` (chunks, seeds): the Student t 95 %
    interval of the mean, clipped to [0, 1] for a rate (:func:`is_rate`)."""
    m, h = mean_ci95(values, axis=1)
    h = np.nan_to_num(h)  # one seed: no band
    lo, hi = m - h, m + h
    if is_rate(metric):
        lo, hi = np.clip(lo, 0.0, 1.0), np.clip(hi, 0.0, 1.0)
    return m, lo, hi


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (files, no display). Imported on first use:
    matplotlib takes over a second to import, and most commands draw nothing."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: str | Path) -> Path:
    """Lay out ``fig``, write it to ``path`` (PNG at :data:`FIGURE_DPI`), close it; the path."""
    plt = pyplot()
    fig.tight_layout()
    fig.savefig(path, dpi=FIGURE_DPI)
    plt.close(fig)
    return Path(path)


def _file_name(metric: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", metric) + ".png"


def plot_names(curves: dict[str, np.ndarray]) -> list[str]:
    """The file names :func:`plot_curves` writes for ``curves``."""
    return [_file_name(k) for k, a in curves.items() if k != "episodes" and a.ndim == 3]


def point_label(values: dict[str, Any]) -> str:
    return ", ".join(f"{p.rsplit('.', 1)[-1]}={v}" for p, v in values.items()) or "run"


def plot_curves(curves: dict[str, np.ndarray], points: list[dict[str, Any]], out_dir: Path,
                title: str = "", percent: bool = False) -> list[Path]:
    """Write ``<metric>.png`` for every scalar metric of ``curves[metric][point, chunk, seed]``
    (with ``percent``, a rate's curve in %).

    The x axis is cumulative episodes (mean over seeds) when an ``episodes`` metric exists,
    else the chunk number. Bands: :func:`band`. Each sweep point has its own line style, so
    coinciding curves stay visible.
    """
    plt = pyplot()
    paths = []
    episodes = curves.get("episodes")
    for name, arr in curves.items():
        if name == "episodes" or arr.ndim != 3:
            continue
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        seeds = arr.shape[2]
        scale = 100.0 if percent and is_rate(name) else 1.0
        for p, values in enumerate(points):
            y = arr[p]
            ok = ~np.all(np.isnan(y), axis=1)
            y = y[ok]
            if episodes is not None:
                x = np.nancumsum(np.nanmean(episodes[p][ok], axis=1))
                xlabel = "episodes"
            else:
                x = np.arange(1, y.shape[0] + 1)
                xlabel = "chunk"
            m, lo, hi = (scale * v for v in band(name, y))
            (line,) = ax.plot(x, m, label=point_label(values),
                              linestyle=LINESTYLES[p % len(LINESTYLES)], lw=1.5 + 0.5 * (p == 0))
            if seeds > 1:
                ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(f"{name} (%)" if scale != 1.0 else name)
        ax.set_title(f"{title} ({seeds} seeds, 95% band)" if title else f"{seeds} seeds")
        if len(points) > 1 or points[0]:
            ax.legend(fontsize="small")
        ax.grid(alpha=0.3)
        paths.append(save_figure(fig, Path(out_dir) / _file_name(name)))
    return paths


FIGURE_SUFFIXES = (".png", ".svg")  #: the files :func:`plot_sweep` writes


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _sweep_lines(records: list[dict[str, Any]], x: str, others: list[str]
                 ) -> tuple[dict[str, list[dict[str, Any]]], dict[str, int]]:
    """``records`` of one metric, one list per value of the ``others`` columns (the label
    of a line), each sorted by ``x`` when every ``x`` is a number; with the tick of each
    ``x`` value that is not (its text -> position)."""
    lines: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        label = point_label({c: r[c] for c in others}) if others else ""
        lines.setdefault(label, []).append(r)
    ticks: dict[str, int] = {}
    if all(_is_number(r[x]) for r in records):
        for rs in lines.values():
            rs.sort(key=lambda r: r[x])
    else:
        for r in records:
            ticks.setdefault(str(r[x]), len(ticks))
    return lines, ticks


def _metric_records(run: Any, y: str) -> list[dict[str, Any]]:
    """:func:`vbl.engine.export.final_stats` of metric ``y``: ``Program.final``'s, else the
    last chunk's; a ParamError listing the metrics when there is none."""
    from vbl.engine.export import final_stats  # export imports this module

    stats = final_stats(run)
    records = ([r for r in stats if r["metric"] == y and r["source"] == "final"]
               or [r for r in stats if r["metric"] == y])
    if not records:
        have = ", ".join(sorted({r["metric"] for r in stats})) or "none yet"
        raise ParamError(f"{y!r} is not a metric of {run.folder} (metrics: {have})")
    return records


def plot_sweep(run: Any, x: str, y: str, out: str | Path | None = None) -> Path:
    """Final metric ``y`` of a run folder against its swept parameter ``x``: the mean over
    seeds and its 95 % interval per sweep point, one line per value of the other swept
    parameters (:func:`vbl.engine.export.final_stats`: ``Program.final``'s metric, else the
    last logged chunk's).

    ``run``: a run folder (finished, running or merged) or its
    :class:`~vbl.engine.export.RunRows`; ``x``: a swept path or its last part; ``out``: a
    ``.png`` or ``.svg`` file (default ``<y>_vs_<x>.png`` in the current folder). Returns
    the path. Raises ParamError for an unknown ``x`` or ``y`` or another file type."""
    plt = pyplot()
    from vbl.engine.export import read_run, swept_path  # export imports this module

    run = read_run(run)
    path = swept_path(run, x)
    out = Path(out) if out is not None else Path(_file_name(f"{y}_vs_{path}"))
    if out.suffix.lower() not in FIGURE_SUFFIXES:
        raise ParamError(f"{out}: the plot is written as {' or '.join(FIGURE_SUFFIXES)}")
    records = _metric_records(run, y)
    col = run.column(path)
    others = [run.column(p) for p in run.sweep if p != path]
    lines, ticks = _sweep_lines(records, col, others)
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for i, (label, rs) in enumerate(lines.items()):
        xs = [ticks[str(r[col])] if ticks else r[col] for r in rs]
        m, lo, hi = (np.array([r[k] for r in rs], dtype=np.float64)
                     for k in ("mean", "lower", "upper"))
        err = np.nan_to_num(np.stack([m - lo, hi - m]))  # no interval: the mean alone
        ax.errorbar(xs, m, yerr=err, label=label or None, marker="o", capsize=3,
                    linestyle=LINESTYLES[i % len(LINESTYLES)])
    if ticks:
        ax.set_xticks(list(ticks.values()), list(ticks))
    what = "final" if records[0]["source"] == "final" else "last chunk"
    ax.set_xlabel(path)
    ax.set_ylabel(f"{y} ({what})")
    ax.set_title(f"{run.experiment}: {y} against {path.rsplit('.', 1)[-1]} "
                 f"({max(r['seeds'] for r in records)} seeds, 95% interval)",
                 fontsize="medium")
    if others:
        ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    return save_figure(fig, out)
