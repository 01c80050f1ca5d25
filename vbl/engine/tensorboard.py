"""Live learning curves in TensorBoard (``vbl run --tensorboard DIR``): every metrics row a
run appends to ``metrics.jsonl`` also goes to event files (tensorboardX), so a running
sweep can be watched with ``tensorboard --logdir DIR``.

Each sweep point is a TensorBoard run, ``DIR/p<point>_<swept values>/``; its scalar
metrics are ``<metric>/mean``, ``<metric>/lower`` and ``<metric>/upper`` (the mean over
seeds and its 95 % band, :func:`vbl.engine.plots.band`: a rate's kept in [0, 1], the
mean alone for one seed) at step = chunks done, and ``Program.final``'s metrics are
``final/<metric>/...`` at the point's last chunk. A custom-scalars layout draws each
metric's band ("95 % band over seeds"). A resumed run hides what an earlier run wrote
past the chunk it resumes from (``purge_step``).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from vbl.engine.errors import EngineError
from vbl.engine.plots import is_rate, point_label

__all__ = ["TensorBoardLog", "require_tensorboardx", "point_run_name"]

BAND_CATEGORY = "95 % band over seeds"  #: the custom-scalars category of the bands


def require_tensorboardx() -> None:
    """An EngineError unless tensorboardX can be imported (before a run starts)."""
    try:
        import tensorboardX  # noqa: F401
    except ImportError:
        raise EngineError("--tensorboard needs tensorboardX: pip install "
                          "'vbl[tensorboard]'") from None


def point_run_name(point: int, values: dict[str, Any]) -> str:
    """The TensorBoard run (sub-folder) of sweep point ``point`` with swept ``values``,
    e.g. ``p1_discount=0.95,initial_difficulty=1.0`` (``p0_run`` without a sweep)."""
    label = point_label(values).replace(", ", ",")
    return f"p{point}_" + re.sub(r"[^A-Za-z0-9_.,=+-]", "_", label)


def _band(metric: str, st: dict[str, Any]) -> tuple[float, float, float] | None:
    """(mean, lower, upper) of a row's scalar metric statistics (``seed_stats``); None for
    an array metric."""
    mean, half = st.get("mean"), st.get("ci95")
    if isinstance(mean, list):
        return None
    m = float("nan") if mean is None else float(mean)
    h = 0.0 if half is None else float(half)  # one seed (or NaN): no band
    lo, hi = m - h, m + h
    if is_rate(metric):
        lo, hi = float(np.clip(lo, 0.0, 1.0)), float(np.clip(hi, 0.0, 1.0))
    return m, lo, hi


class TensorBoardLog:
    """A :class:`~vbl.engine.results.MetricsLog` that also writes every appended row to
    TensorBoard event files under ``logdir`` (see the module's docstring); rows of an
    experiment's own loop (no sweep point) go to the run ``own_loop`` as they are."""

    def __init__(self, log: Any, logdir: str | Path):
        require_tensorboardx()
        self.log = log
        self.logdir = Path(logdir)
        self.path = log.path
        self.enabled = log.enabled
        self._writers: dict[Any, Any] = {}
        self._chunks: dict[int, int] = {}  # point -> chunks done (last row's)
        self._layout_written = False

    def truncate_after(self, step: int) -> int:
        return self.log.truncate_after(step)

    def _writer(self, key: Any, name: str, first_step: int):
        if key not in self._writers:
            from tensorboardX import SummaryWriter

            # purge_step: TensorBoard hides what an earlier run wrote from this step on
            self._writers[key] = SummaryWriter(str(self.logdir / name), purge_step=first_step,
                                               flush_secs=10)
        return self._writers[key]

    def _layout(self, writer: Any, metrics: list[str]) -> None:
        """The custom-scalars layout, once: one margin chart (mean and band) per metric."""
        if self._layout_written:
            return
        writer.add_custom_scalars({BAND_CATEGORY: {
            m: ["Margin", [f"{m}/mean", f"{m}/lower", f"{m}/upper"]] for m in metrics}})
        self._layout_written = True

    def append(self, rows: list[dict[str, Any]]) -> None:
        """Append ``rows`` to ``metrics.jsonl``, then write them as scalars and flush."""
        rows = list(rows)
        self.log.append(rows)
        for r in rows:
            if not isinstance(r.get("point"), int):
                self._own_row(r)
                continue
            p = r["point"]
            final = r["chunk"] == "final"
            step = self._chunks.get(p, 0) if final else r["chunk"] + 1
            self._chunks[p] = max(self._chunks.get(p, 0), step)
            w = self._writer(p, point_run_name(p, r.get("values", {})), step)
            bands = {k: b for k, st in r["metrics"].items() if (b := _band(k, st)) is not None}
            if not final:
                self._layout(w, list(bands))
            for k, (m, lo, hi) in bands.items():
                tag = f"final/{k}" if final else k
                w.add_scalar(f"{tag}/mean", m, step)
                w.add_scalar(f"{tag}/lower", lo, step)
                w.add_scalar(f"{tag}/upper", hi, step)
        for w in self._writers.values():
            w.flush()

    def _own_row(self, r: dict[str, Any]) -> None:
        w = self._writer(None, "own_loop", int(r["step"]))
        for k, v in r.get("metrics", {}).items():
            a = np.asarray(v)
            if a.ndim == 0 and a.dtype.kind in "iuf":  # scalars only
                w.add_scalar(k, float(a), int(r["step"]))

    def close(self) -> None:
        """Flush and close every event file."""
        for w in self._writers.values():
            w.close()
        self._writers.clear()
