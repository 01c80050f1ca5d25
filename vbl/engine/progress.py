"""Progress bar over chunks (tqdm): episodes per second and the current success rate."""

from __future__ import annotations

import os
import sys
import time
from typing import Any

import numpy as np

__all__ = ["auto_quiet", "Progress"]


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

            self._bar = tqdm(total=total, initial=initial, desc=desc, unit="chunk",
                             dynamic_ncols=True, file=sys.stderr)
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
        if "success_rate" in metrics:
            post["success"] = f"{float(np.mean(metrics['success_rate'])):.3f}"
        self._bar.set_postfix(post, refresh=False)
        self._bar.update(1)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
