"""Learning-curve figures (matplotlib Agg): one line per sweep point, 95% band over seeds."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from vbl.stats import mean_ci95

__all__ = ["point_label", "plot_curves", "plot_names", "is_rate", "band", "save_figure",
           "FIGURE_DPI"]

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


def save_figure(fig: Any, path: str | Path) -> Path:
    """Lay out ``fig``, write it to ``path`` (PNG at :data:`FIGURE_DPI`), close it; the path."""
    import matplotlib.pyplot as plt

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
                title: str = "") -> list[Path]:
    """Write ``<metric>.png`` for every scalar metric of ``curves[metric][point, chunk, seed]``.

    The x axis is cumulative episodes (mean over seeds) when an ``episodes`` metric exists,
    else the chunk number. Bands: :func:`band`. Each sweep point has its own line style, so
    coinciding curves stay visible.
    """
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    paths = []
    episodes = curves.get("episodes")
    for name, arr in curves.items():
        if name == "episodes" or arr.ndim != 3:
            continue
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        seeds = arr.shape[2]
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
            m, lo, hi = band(name, y)
            (line,) = ax.plot(x, m, label=point_label(values),
                              linestyle=LINESTYLES[p % len(LINESTYLES)], lw=1.5 + 0.5 * (p == 0))
            if seeds > 1:
                ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(name)
        ax.set_title(f"{title} ({seeds} seeds, 95% band)" if title else f"{seeds} seeds")
        if len(points) > 1 or points[0]:
            ax.legend(fontsize="small")
        ax.grid(alpha=0.3)
        paths.append(save_figure(fig, Path(out_dir) / _file_name(name)))
    return paths
