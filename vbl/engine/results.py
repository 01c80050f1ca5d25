"""The run folder: ``config.json``, ``metrics.jsonl``, ``summary.json``, plots, checkpoints."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from vbl.engine.errors import EngineError
from vbl.stats import mean_ci95

__all__ = ["MetricsLog", "seed_stats", "read_metrics", "metric_arrays", "point_summaries",
           "write_json", "read_json", "nan_to_null"]


def _clean(x: Any) -> Any:
    """NumPy -> JSON-able lists/floats (NaN/inf -> None)."""
    a = np.asarray(x)
    if a.dtype.kind == "f":
        a = a.astype(np.float64)
        if a.ndim == 0:
            v = float(a)
            return v if math.isfinite(v) else None
        return [_clean(v) for v in a]
    return a.tolist()


def nan_to_null(obj: Any) -> Any:
    """``obj`` with every non-finite float (a Python or NumPy scalar, in nested dicts,
    lists and tuples) as None: JSON has no NaN or infinity."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: nan_to_null(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [nan_to_null(v) for v in obj]
    return obj


def seed_stats(values: np.ndarray) -> dict[str, Any]:
    """``values[seeds, ...]`` -> mean, std (ddof 1; 0 for one seed), ci95 half-width
    (:func:`vbl.stats.mean_ci95`; None for one seed), per_seed."""
    v = np.asarray(values, dtype=np.float64)
    mean, ci = mean_ci95(v)
    std = v.std(axis=0, ddof=1) if v.shape[0] > 1 else np.zeros_like(mean)
    return {"mean": _clean(mean), "std": _clean(std), "ci95": _clean(ci),
            "per_seed": _clean(v)}


def write_json(path: Path, obj: Any) -> None:
    """Write ``obj`` as JSON atomically (a temporary file, then a rename)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    try:
        tmp.write_text(json.dumps(nan_to_null(obj), indent=1, default=_clean,
                                  allow_nan=False) + "\n")
        os.replace(tmp, path)
    except BaseException as e:
        tmp.unlink(missing_ok=True)
        if isinstance(e, OSError) and e.filename is None:
            e.filename = str(path)  # a failed write names no file: the error line does
        raise


def read_json(path: Path) -> Any:
    return json.loads(Path(path).read_text())


class MetricsLog:
    """Append-only JSON lines; :meth:`truncate_after` drops lines past a checkpoint."""

    def __init__(self, path: Path, enabled: bool = True):
        self.path = Path(path)
        self.enabled = enabled

    def append(self, rows: Iterable[dict[str, Any]]) -> None:
        if not self.enabled:
            return
        text = "".join(json.dumps(nan_to_null(r), default=_clean, allow_nan=False) + "\n"
                       for r in rows)
        try:
            with open(self.path, "a") as f:
                f.write(text)
                f.flush()
        except OSError as e:
            if e.filename is None:  # a failed write names no file: the error line does
                e.filename = str(self.path)
            raise

    def truncate_after(self, step: int) -> int:
        """Keep rows with ``row["step"] <= step`` (a torn last line is dropped; any other
        malformed line is an error); return how many were kept."""
        if not self.enabled or not self.path.exists():
            return 0
        keep = [line + "\n" for line, row in _lines(self.path) if row["step"] <= step]
        tmp = self.path.with_suffix(".jsonl.tmp")
        try:
            tmp.write_text("".join(keep))
            os.replace(tmp, self.path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        return len(keep)


def _lines(path: Path) -> list[tuple[str, dict[str, Any]]]:
    """``(line, row)`` of every complete line of a ``metrics.jsonl``.

    Rows are appended whole, so only the last line can be torn (a crash or a full disk in
    the middle of a write): a last line without its newline that does not parse is
    ignored. Any other line that is not a metrics row raises EngineError.
    """
    try:
        text = Path(path).read_bytes().decode()
    except (OSError, UnicodeDecodeError) as e:
        raise EngineError(f"cannot read {path}: {e}") from e
    lines = text.split("\n")
    tail = lines.pop()  # "" when the file ends with a newline
    out = []
    for i, line in enumerate(lines, 1):
        row = _row(line)
        if row is None:
            raise EngineError(f"{path} line {i} is not a metrics row ({line[:60]!r}); the file "
                              f"was changed or damaged: restore it, or start again with "
                              f"--overwrite")
        out.append((line, row))
    row = _row(tail) if tail else None
    if row is not None:
        out.append((tail, row))
    return out


def _row(line: str) -> dict[str, Any] | None:
    try:
        row = json.loads(line)
    except ValueError:
        return None
    ok = isinstance(row, dict) and isinstance(row.get("step"), int) and not isinstance(
        row["step"], bool)
    return row if ok else None


def metric_arrays(rows: list[dict[str, Any]], points: int, chunks: int | None = None
                  ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """``(curves, final)`` of ``metrics.jsonl`` rows: ``curves[metric]`` (points, chunks,
    seeds...) from the per-chunk rows, ``final[metric]`` (points, seeds...) from the
    ``"final"`` rows, NaN where a row is missing; ``chunks`` None: the rows' last chunk + 1."""
    if chunks is None:
        chunks = 1 + max((r["chunk"] for r in rows if isinstance(r.get("chunk"), int)),
                         default=-1)
    curves: dict[str, np.ndarray] = {}
    final: dict[str, np.ndarray] = {}
    for r in rows:
        p = r["point"]
        for k, st in r["metrics"].items():
            v = np.asarray(st["per_seed"], dtype=np.float64)
            if r["chunk"] == "final":
                final.setdefault(k, np.full((points,) + v.shape, np.nan))[p] = v
            else:
                curves.setdefault(k, np.full((points, chunks) + v.shape, np.nan))[
                    p, r["chunk"]] = v
    return curves, final


def point_summaries(curves: dict[str, np.ndarray], final: dict[str, np.ndarray],
                    points: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``summary.json``'s ``points``: per sweep point its ``values``, the seed statistics
    of every metric's last logged chunk (``last_chunk``, no per-seed values) and of its
    ``final`` metrics (with per-seed values); arrays as :func:`metric_arrays` gives them."""
    out = []
    for p, values in enumerate(points):
        last = {}
        for k, a in curves.items():
            logged = a[p][~np.all(np.isnan(a[p].reshape(a.shape[1], -1)), axis=1)]
            if len(logged):
                last[k] = {n: v for n, v in seed_stats(logged[-1]).items() if n != "per_seed"}
        out.append({"point": p, "values": values, "last_chunk": last,
                    "final": {k: seed_stats(a[p]) for k, a in final.items()}})
    return out


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """All rows of a ``metrics.jsonl`` (a torn last line is ignored; any other malformed
    line raises EngineError)."""
    p = Path(path)
    if not p.exists():
        return []
    return [row for _, row in _lines(p)]
