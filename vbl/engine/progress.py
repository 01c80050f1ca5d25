"""Progress bar over chunks (tqdm): episodes per second and the current success rate."""

from __future__ import annotations

import os
import shutil
import sys
import time
from typing import Any

import numpy as np

__all__ = ["auto_quiet", "Progress", "bar_width", "SUCCESS_METRICS"]

SUCCESS_METRICS = ("eval_success", "greedy_success", "success_rate", "train_success",
                   "chunk_success")
"""Per-chunk metrics the bar shows, the first one present, under its own name: the
evaluation of the policy learned so far before training success (with exploration)."""

DEFAULT_COLUMNS = 100  #: bar width when the terminal reports no usable width
MIN_COLUMNS = 40  #: narrower reported widths are taken as unusable (e.g. 0 in some IDEs)


def bar_width() -> int | None:
    """None (follow the terminal) when it reports a usable width, else DEFAULT_COLUMNS."""
    cols = shutil.get_terminal_size((0, 0)).columns
    return None if cols >= MIN_COLUMNS else DEFAULT_COLUMNS


def auto_quiet() -> bool:
    """True when stderr is not a terminal or ``CI`` is set to true."""
    ci = os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")
    return ci or not sys.stderr.isatty()


class Progress:
    """``update(metrics, seconds)`` after every chunk; ``metrics`` are host arrays with the
    learner axis first."""

    def __init__(self, total: int, initial: int = 0, desc: str = "", quiet: bool = False):
        self._bar = None
        if not quiet:
            from tqdm.auto import tqdm

            width = bar_width()
            self._bar = tqdm(total=total, initial=initial, desc=desc, unit="chunk",
                             dynamic_ncols=width is None, ncols=width, file=sys.stderr)
        self._t = time.perf_counter()

    def update(self, metrics: dict[str, Any], seconds: float | None = None) -> None:
        now = time.perf_counter()
        dt = seconds if seconds is not None else now - self._t
        self._t = now
        if self._bar is None:
            return
        post = {}
        if "episodes" in metrics and dt > 0:
            post["episodes/s"] = f"{float(np.sum(metrics['episodes'])) / dt:,.0f}"
        shown = next((m for m in SUCCESS_METRICS if m in metrics), None)
        if shown is not None:
            post[shown] = f"{float(np.mean(metrics[shown])):.3f}"
        self._bar.set_postfix(post, refresh=False)
        self._bar.update(1)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
