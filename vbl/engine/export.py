"""A run folder as tables (``vbl export``): every metric value per sweep point, seed and
chunk, and each point's final metrics with their 95 % intervals (:mod:`vbl.stats`).

Both tables come from ``config.json`` and ``metrics.jsonl`` alone, so a finished, a
running and a merged run folder (and a shard's, holding its own seeds) all read alike.
The records of :func:`final_stats` need nothing beyond NumPy; the DataFrames need pandas
(``pip install 'vbl[data]'``, and pyarrow for Parquet).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vbl.engine.errors import EngineError
from vbl.engine.plots import is_rate
from vbl.engine.results import read_metrics
from vbl.engine.runfolder import read_run_spec
from vbl.params import ParamError
from vbl.stats import bounded_ci95, mean_ci95

__all__ = ["RunRows", "read_run", "long_columns", "run_table", "final_table", "final_stats",
           "swept_path", "export_run", "FORMATS"]

FORMATS = ("csv", "parquet")  #: the file formats of :func:`export_run`
RESERVED = ("point", "seed", "chunk", "final", "metric", "value", "source", "seeds", "mean",
            "std", "ci95", "lower", "upper")
"""Column names of the tables; a swept parameter of the same name is ``NAME (swept)``."""


@dataclass(frozen=True)
class RunRows:
    """What the tables are made of: a run folder's ``config.json`` and metric rows.

    Attributes:
      folder: the run folder.
      experiment: the experiment's name.
      sweep: ``{path: [values]}`` of the swept parameters (empty when none).
      seeds: seeds per sweep point.
      rows: the ``metrics.jsonl`` rows (one per sweep point and chunk, and ``"final"``).
    """

    folder: Path
    experiment: str
    sweep: dict[str, list[Any]]
    seeds: int
    rows: list[dict[str, Any]]

    def column(self, path: str) -> str:
        """The table column of swept parameter ``path``."""
        return f"{path} (swept)" if path in RESERVED else path


def read_run(folder: str | Path | RunRows) -> RunRows:
    """The :class:`RunRows` of a run folder (finished, running or merged); an EngineError
    when ``folder`` is not a vbl run folder of this format or its rows are not sweep
    points' (an experiment's own loop, ``Experiment.run``, logs rows of its own)."""
    if isinstance(folder, RunRows):
        return folder
    folder = Path(folder)
    spec = read_run_spec(folder)
    rows = read_metrics(folder / "metrics.jsonl")
    for i, r in enumerate(rows, 1):
        ok = (isinstance(r.get("point"), int) and isinstance(r.get("values"), dict)
              and isinstance(r.get("metrics"), dict)
              and (r.get("chunk") == "final" or isinstance(r.get("chunk"), int)))
        if not ok:
            raise EngineError(f"{folder}/metrics.jsonl line {i} is not a sweep point's metrics "
                              f"row (an experiment's own loop logs rows of its own): only "
                              f"runs of a program export as tables")
    return RunRows(folder, str(spec["experiment"]), dict(spec.get("sweep") or {}),
                   int(spec.get("seeds", 1)), rows)


def _elements(name: str, per_seed: Any) -> list[tuple[str, np.ndarray]]:
    """``(metric, values[seeds])`` of a row's metric: a scalar metric as is, an array
    metric one element at a time, named ``name[i]`` (``name[i,j]``, ...)."""
    v = np.asarray(per_seed, dtype=np.float64)  # null (NaN, inf in the file) -> NaN
    if v.ndim == 1:
        return [(name, v)]
    rest = v.shape[1:]
    flat = v.reshape(v.shape[0], -1)
    return [(f"{name}[{','.join(map(str, np.unravel_index(j, rest)))}]", flat[:, j])
            for j in range(flat.shape[1])]


def _param_column(values: list[Any]) -> np.ndarray:
    """A swept parameter's values as one column (tuples as their text)."""
    if any(isinstance(v, (list, tuple)) for v in values):
        return np.asarray([str(tuple(v)) if isinstance(v, list) else str(v) for v in values],
                          dtype=object)
    return np.asarray(values)


def long_columns(run: str | Path | RunRows) -> dict[str, Any]:
    """The columns of :func:`run_table` as NumPy arrays (``chunk`` -1 on ``final`` rows)."""
    run = read_run(run)
    seg_row, seg_len, names, values, seeds = [], [], [], [], []
    for i, r in enumerate(run.rows):
        first = int(r["seeds"][0]) if isinstance(r.get("seeds"), list) else 0
        for k, st in r["metrics"].items():
            for name, v in _elements(k, st["per_seed"]):
                seg_row.append(i)
                seg_len.append(v.size)
                names.append(name)
                values.append(v)
                seeds.append(np.arange(first, first + v.size))
    at = np.repeat(np.asarray(seg_row, dtype=np.int64), seg_len)
    chunks = np.asarray([-1 if r["chunk"] == "final" else r["chunk"] for r in run.rows],
                        dtype=np.int64)
    cols: dict[str, Any] = {"point": np.asarray([r["point"] for r in run.rows],
                                                dtype=np.int64)[at]}
    for path in run.sweep:
        cols[run.column(path)] = _param_column([r["values"].get(path) for r in run.rows])[at]
    cols["seed"] = np.concatenate(seeds) if seeds else np.zeros(0, np.int64)
    cols["chunk"] = chunks[at]
    cols["final"] = cols["chunk"] < 0
    cols["metric"] = np.repeat(np.asarray(names, dtype=object), seg_len)
    cols["value"] = np.concatenate(values) if values else np.zeros(0)
    return cols


def _pandas():
    try:
        import pandas
    except ImportError:
        raise EngineError("tables of a run need pandas: pip install 'vbl[data]'") from None
    return pandas


def run_table(run: str | Path | RunRows):
    """Every metric value of a run folder as a tidy pandas DataFrame, one row per (sweep
    point, seed, chunk, metric), in the order of ``metrics.jsonl``.

    Columns: ``point`` (index of the sweep point), one column per swept parameter (its
    dotted path), ``seed`` (index, as the engine keys it), ``chunk`` (0-based; <NA> on the
    rows of ``Program.final``), ``final`` (bool), ``metric`` (an array metric's elements as
    ``name[i]``), ``value`` (float64; NaN where the file holds null)."""
    pd = _pandas()
    cols = long_columns(run)
    cols["chunk"] = pd.arrays.IntegerArray(np.maximum(cols["chunk"], 0), cols["final"])
    return pd.DataFrame(cols)


def _stats(values: np.ndarray, rate: bool) -> dict[str, float]:
    """Mean, std (ddof 1), 95 % half-width (:func:`vbl.stats.mean_ci95`) and interval of a
    metric's per-seed ``values``; a rate's interval is kept in [0, 1]
    (:func:`vbl.stats.bounded_ci95`, NaN when too few seeds); NaN interval for one seed."""
    mean, half = mean_ci95(values)
    std = float(values.std(ddof=1)) if values.size > 1 else 0.0
    lo, hi = mean - half, mean + half
    if rate and half == half:
        b = bounded_ci95(values, 0.0, 1.0)
        lo, hi = (b[1], b[2]) if b is not None else (float("nan"), float("nan"))
    return {"seeds": int(values.size), "mean": mean, "std": std, "ci95": half,
            "lower": lo, "upper": hi}


def final_stats(run: str | Path | RunRows) -> list[dict[str, Any]]:
    """One record per (sweep point, metric) of a run's final metrics: those of
    ``Program.final`` (``source`` "final") and every metric of the point's last logged
    chunk (``source`` "last_chunk", with its ``chunk``), as dicts with ``point``, the swept
    parameters' columns, ``metric``, ``source``, ``chunk`` (None for "final"), ``seeds``,
    ``mean``, ``std``, ``ci95`` (the Student t half-width of the mean, NaN for one seed),
    ``lower``, ``upper`` (mean -/+ ci95; a rate's, :func:`vbl.engine.plots.is_rate`, kept
    in [0, 1], NaN with too few seeds, :func:`vbl.stats.bounded_ci95`)."""
    run = read_run(run)
    last: dict[int, dict[str, Any]] = {}
    final: dict[int, dict[str, Any]] = {}
    for r in run.rows:
        if r["chunk"] == "final":
            final[r["point"]] = r
        elif r["point"] not in last or r["chunk"] >= last[r["point"]]["chunk"]:
            last[r["point"]] = r
    out = []
    for p in sorted(set(last) | set(final)):
        for source, r in (("final", final.get(p)), ("last_chunk", last.get(p))):
            if r is None:
                continue
            head = {"point": p, **{run.column(k): r["values"].get(k) for k in run.sweep}}
            for k, st in r["metrics"].items():
                for name, v in _elements(k, st["per_seed"]):
                    out.append({**head, "metric": name, "source": source,
                                "chunk": None if source == "final" else r["chunk"],
                                **_stats(v, is_rate(name))})
    return out


def final_table(run: str | Path | RunRows):
    """:func:`final_stats` as a pandas DataFrame (``chunk`` Int64, <NA> for "final")."""
    pd = _pandas()
    df = pd.DataFrame(final_stats(run))
    if "chunk" in df:
        df["chunk"] = df["chunk"].astype("Int64")
    return df


def swept_path(run: str | Path | RunRows, name: str) -> str:
    """The swept parameter ``name`` names: its dotted path, or the path's last part when
    one path ends so; a ParamError listing the swept paths otherwise."""
    run = read_run(run)
    if name in run.sweep:
        return name
    ends = [p for p in run.sweep if p.rsplit(".", 1)[-1] == name]
    if len(ends) == 1:
        return ends[0]
    have = ", ".join(run.sweep) or "none: the run sweeps nothing"
    raise ParamError(f"{name!r} is not a swept parameter of {run.folder} (swept: {have})")


def export_run(run: str | Path | RunRows, out: str | Path | None = None,
               fmt: str | None = None, final: bool = False) -> tuple[Path, int]:
    """Write :func:`run_table` (or, with ``final``, :func:`final_table`) of a run folder to
    ``out`` as CSV or Parquet (``fmt``; default: ``out``'s extension, else CSV); ``out``
    None: ``<run folder name>[-final].<fmt>`` in the current folder. Returns ``(path,
    rows)``."""
    run = read_run(run)
    if fmt is None:
        ext = Path(out).suffix.lstrip(".").lower() if out is not None else ""
        fmt = ext if ext in FORMATS else "csv"
    if fmt not in FORMATS:
        raise ParamError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    if out is None:
        out = Path(f"{run.folder.resolve().name}{'-final' if final else ''}.{fmt}")
    df = final_table(run) if final else run_table(run)
    out = Path(out)
    try:
        if fmt == "csv":
            df.to_csv(out, index=False)
        else:
            df.to_parquet(out, index=False)
    except ImportError as e:
        raise EngineError(f"Parquet needs pyarrow: pip install 'vbl[data]' ({e})") from None
    except OSError as e:
        raise EngineError(f"cannot write {out}: {e.strerror or e}") from e
    return out, len(df)
