"""The run folder: ``config.json``, ``metrics.jsonl``, ``summary.json``, plots, checkpoints."""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from vbl.engine.config import EngineError

__all__ = ["prepare_run_dir", "MetricsLog", "seed_stats", "t_quantile_975", "read_metrics",
           "write_json", "read_json"]


# 0.975 quantiles of Student's t for 1..30 degrees of freedom (standard tables).
_T975 = (12.706205, 4.302653, 3.182446, 2.776445, 2.570582, 2.446912, 2.364624, 2.306004,
         2.262157, 2.228139, 2.200985, 2.178813, 2.160369, 2.144787, 2.131450, 2.119905,
         2.109816, 2.100922, 2.093024, 2.085963, 2.079614, 2.073873, 2.068658, 2.063899,
         2.059539, 2.055529, 2.051831, 2.048407, 2.045230, 2.042272)


def t_quantile_975(df: int) -> float:
    """0.975 quantile of Student's t with ``df`` degrees of freedom (95% two-sided interval).

    A table for ``df <= 30``, the Cornish-Fisher expansion beyond (error < 1e-5).
    """
    if df < 1:
        return float("nan")
    if df <= len(_T975):
        return _T975[df - 1]
    z = 1.959963984540054
    g1 = (z**3 + z) / 4
    g2 = (5 * z**5 + 16 * z**3 + 3 * z) / 96
    g3 = (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / 384
    return z + g1 / df + g2 / df**2 + g3 / df**3


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


def seed_stats(values: np.ndarray) -> dict[str, Any]:
    """``values[seeds, ...]`` -> mean, std (ddof 1), ci95 half-width, per_seed."""
    v = np.asarray(values, dtype=np.float64)
    s = v.shape[0]
    mean = v.mean(axis=0)
    std = v.std(axis=0, ddof=1) if s > 1 else np.zeros_like(mean)
    ci = t_quantile_975(s - 1) * std / math.sqrt(s) if s > 1 else np.zeros_like(mean)
    return {"mean": _clean(mean), "std": _clean(std), "ci95": _clean(ci),
            "per_seed": _clean(v)}


def write_json(path: Path, obj: Any) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=_clean) + "\n")
    os.replace(tmp, path)


def read_json(path: Path) -> Any:
    return json.loads(Path(path).read_text())


def prepare_run_dir(out: str | Path | None, name: str, *, resume: bool, overwrite: bool,
                    primary: bool = True) -> Path:
    """Create (or reuse, for ``resume``) the run folder and check that it is writable.

    Never overwrites: an existing non-empty folder needs ``resume`` or ``overwrite``; and
    ``overwrite`` only deletes folders that hold a vbl run (a ``config.json``).
    """
    if resume and overwrite:
        raise EngineError("--resume and --overwrite exclude each other")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = Path(out) if out is not None else Path("runs") / f"{name}-{stamp}"
    if not primary:  # process 0 checks and creates the folder
        return path
    if path.exists() and not path.is_dir():
        raise EngineError(f"output folder {path} exists and is not a folder")
    nonempty = path.is_dir() and any(path.iterdir())
    if nonempty and not resume:
        if not overwrite:
            raise EngineError(f"output folder {path} exists and is not empty; use --resume to "
                              f"continue it, --overwrite to replace it, or another --out")
        if not (path / "config.json").exists():
            raise EngineError(f"refusing to --overwrite {path}: it holds no vbl run "
                              f"(no config.json); remove it yourself or pick another --out")
        if primary:
            shutil.rmtree(path)
    if primary:
        try:
            path.mkdir(parents=True, exist_ok=True)
            probe = path / f".write-test-{os.getpid()}"
            probe.write_text("ok")
            probe.unlink()
        except OSError as e:
            raise EngineError(f"cannot write to output folder {path}: {e.strerror or e}") from e
    return path


class MetricsLog:
    """Append-only JSON lines; :meth:`truncate_after` drops lines past a checkpoint."""

    def __init__(self, path: Path, enabled: bool = True):
        self.path = Path(path)
        self.enabled = enabled

    def append(self, rows: Iterable[dict[str, Any]]) -> None:
        if not self.enabled:
            return
        text = "".join(json.dumps(r, default=_clean) + "\n" for r in rows)
        with open(self.path, "a") as f:
            f.write(text)
            f.flush()

    def truncate_after(self, step: int) -> int:
        """Keep rows with ``row["step"] <= step`` (and drop a torn last line); return kept."""
        if not self.enabled or not self.path.exists():
            return 0
        keep = []
        for line in self.path.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            if int(row.get("step", 0)) <= step:
                keep.append(line + "\n")
        tmp = self.path.with_suffix(".jsonl.tmp")
        tmp.write_text("".join(keep))
        os.replace(tmp, self.path)
        return len(keep)


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """All rows of a ``metrics.jsonl`` (a torn last line is ignored)."""
    rows = []
    p = Path(path)
    if not p.exists():
        return rows
    for line in p.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return rows
