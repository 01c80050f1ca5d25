"""Reports: an experiment's ``report.md`` in its run folder (``vbl run`` and ``vbl
reproduce``), the short table ``vbl run`` prints, and the cells every report shares
(mean ± 95 % interval over seeds, a rate's kept in [0, 1]; verdicts on differences)."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np

from vbl.engine.errors import EngineError, one_line
from vbl.engine.experiment import Experiment, ReportSection, RunResult
from vbl.engine.plots import is_rate
from vbl.engine.runfolder import record_files
from vbl.stats import bounded_ci95, mean_ci95, seeds_to_resolve, t_quantile_975, welch_ci95

__all__ = ["default_section", "run_report", "write_report", "headline_table", "TABLE_COLUMNS",
           "stat_cell", "seeds_cell", "rate_cell", "RATE", "claim", "url_path", "figure_path"]


TABLE_COLUMNS = 100  #: the width ``vbl run``'s terminal table keeps to




def default_section(result: RunResult, percent: bool = False) -> ReportSection:
    """A table of every sweep point's scalar last-chunk and final metrics (mean ± 95 %
    interval over seeds, a rate's kept in [0, 1]: :func:`seeds_cell`; with ``percent``, rates
    in % and their headings marked so); array-valued metrics (e.g. a learned map) stay in
    ``summary.json`` only."""
    lines = []
    for entry in result.summary.get("points", []):
        label = ", ".join(f"{k}={v}" for k, v in entry["values"].items()) or "default config"
        stats = {**{f"{k} (last chunk)": v for k, v in entry.get("last_chunk", {}).items()},
                 **{f"{k} (final)": v for k, v in entry.get("final", {}).items()}}
        stats = {k: v for k, v in stats.items() if not isinstance(v.get("mean"), list)}
        if not lines:
            heads = [_heading(k.split(" (")[0], percent) + k[len(k.split(" (")[0]):]
                     for k in stats]
            lines += ["| point | " + " | ".join(heads) + " |", "|---" * (len(stats) + 1) + "|"]
        lines.append(f"| {label} | " + " | ".join(_cell(k.split(" (")[0], v, percent)
                                                   for k, v in stats.items()) + " |")
    if not lines and "result" in result.summary:
        lines = ["```", str(result.summary["result"]), "```"]
    return ReportSection("\n".join(lines), tuple(result.figures))


def url_path(path: str | Path) -> str:
    """A relative path as a Markdown link target: ``/``-separated and percent-encoded
    (a space, parenthesis or ``#`` in a folder name would end or break the link)."""
    return quote(Path(path).as_posix(), safe="/")


def figure_path(f: str | Path, out_dir: Path) -> Path:
    """A report's figure path, absolute. A relative path is taken from the working directory
    when it exists there (experiments usually return run_dir / name with a relative
    run_dir), else from the run folder."""
    p = Path(f)
    if not p.is_absolute() and not p.exists():
        p = Path(out_dir) / p
    return p.absolute()


def run_report(exp: Experiment, result: RunResult) -> tuple[ReportSection, Path]:
    """Build the experiment's report section (its ``report``, else :func:`default_section`)
    and write it with its figures to ``<run folder>/report.md``. Figures the report writes
    and ``report.md`` are recorded as the run's files (``--overwrite`` replaces them).
    Returns ``(section with absolute figure paths, report.md)``."""
    out_dir = Path(result.out_dir)
    before = {p.name for p in out_dir.iterdir()}
    try:
        section = (exp.report(result) if exp.report is not None
                   else default_section(result, exp.percent))
        figs = tuple(figure_path(f, out_dir) for f in section.figures)
        links = [f"![{f.stem}]({url_path(os.path.relpath(f, out_dir.absolute()))})" for f in figs]
        path = out_dir / "report.md"
        path.write_text("\n".join([f"# {exp.name}", "", exp.description, "",
                                    section.markdown, "", *(f + "\n" for f in links)]) + "\n")
    finally:
        record_files(out_dir, {p.name for p in out_dir.iterdir()} - before)
    return ReportSection(section.markdown, figs), path


def write_report(exp: Experiment, result: RunResult, what: str = "run") -> Path:
    """:func:`run_report` as ``run_experiment`` and ``vbl merge`` write it after the
    ``what`` (the results are written by then): a report that fails is an EngineError
    saying so. Returns ``report.md``."""
    try:
        return run_report(exp, result)[1]
    except Exception as e:  # noqa: BLE001 - the results are written; say so
        raise EngineError(f"the {what} finished (results in {result.out_dir}) but its "
                          f"report failed: {one_line(e)}") from e


def _cell(name: str, st: dict[str, Any], percent: bool = False) -> str:
    """A summary statistic of metric ``name`` as the reports show it: :func:`seeds_cell` of
    its per-seed values (a rate's interval kept in [0, 1]; with ``percent``, a rate in %),
    else mean ± its ``ci95``."""
    m, ci, values = st.get("mean"), st.get("ci95"), st.get("per_seed")
    if not isinstance(m, int | float):
        return str(m)
    if isinstance(values, list) and values and all(isinstance(v, int | float) for v in values):
        if percent and is_rate(name):
            return rate_cell(values, 100.0, ".1f")
        return seeds_cell(values, bounds=RATE if is_rate(name) else None)
    if not isinstance(ci, int | float) or ci != ci:
        return f"{m:.3g}"
    return f"{m:.3g} ± {ci:.2g}"


def headline_table(result: RunResult, exp: Experiment | None = None,
                   width: int = TABLE_COLUMNS) -> str:
    """The short table ``vbl run`` prints: one row per sweep point, the experiment's
    :attr:`~vbl.engine.Experiment.headline` metrics (mean ± 95 % interval over seeds; a
    ``final`` metric, else the last chunk's), or by default the scalar ``final`` metrics then
    the last chunk's, as many as fit ``width`` columns. The full table is in
    ``summary.json``."""
    points = result.summary.get("points", [])
    if not points:
        return _result_line(result.summary.get("result"), width)
    labels = _point_labels(points)
    percent = exp is not None and exp.percent
    cols, left = _fit_columns(labels, _headline_names(points[0], exp), points, width, percent)
    seeds = result.summary.get("seeds", result.seeds)
    note = f"mean ± 95% interval over {seeds} seeds"
    if left:
        note += f"; {len(left)} more metric{'s' * (len(left) != 1)} in summary.json"
    return "\n".join(_aligned(cols, len(points)) + [note])


def _result_line(res: Any, width: int) -> str:
    """The headline of a run without sweep points: its result's keys (a dict) or the result
    itself, cut to ``width`` columns; empty without a result."""
    if res is None:
        return ""
    keys = list(res) if isinstance(res, dict) else []
    text = "result keys: " + ", ".join(keys) if keys else "result: " + str(res)
    return text if len(text) <= width else text[:width - 3] + "..."


def _scalar(st: Any) -> bool:
    return isinstance(st, dict) and isinstance(st.get("mean"), int | float)


def _lookup(entry: dict[str, Any], name: str) -> Any:
    """A point's statistic of metric ``name``: the ``final`` one, else the last chunk's."""
    st = entry.get("final", {}).get(name)
    return st if st is not None else entry.get("last_chunk", {}).get(name)


def _headline_names(first: dict[str, Any], exp: Experiment | None) -> list[str]:
    """The metrics a headline table shows, in order: the experiment's
    :attr:`~vbl.engine.Experiment.headline` ones the first point has as scalars, or by
    default the scalar ``final`` metrics then the last chunk's (but ``episodes``)."""
    if exp is not None and exp.headline:
        return [n for n in exp.headline if _scalar(_lookup(first, n))]
    names = [n for n, st in first.get("final", {}).items() if _scalar(st)]
    names += [n for n, st in first.get("last_chunk", {}).items()
              if _scalar(st) and n not in names and n != "episodes"]
    return names


def _point_labels(points: list[dict[str, Any]]) -> list[str]:
    """Each point's swept values (``path=value, ...``), with the last part of each path only
    when a full label would be longer than 40 characters."""
    full = [", ".join(f"{k}={v}" for k, v in e["values"].items()) or "default config"
            for e in points]
    short = [", ".join(f"{k.rsplit('.', 1)[-1]}={v}" for k, v in e["values"].items())
             or "default config" for e in points]
    return full if max(map(len, full)) <= 40 else short


def _heading(name: str, percent: bool) -> str:
    """A metric's column heading: its name, with `` %`` when its values are shown in %."""
    return f"{name} %" if percent and is_rate(name) else name


def _fit_columns(labels: list[str], names: list[str], points: list[dict[str, Any]],
                 width: int, percent: bool = False
                 ) -> tuple[list[tuple[str, list[str]]], list[str]]:
    """``([(heading, cells)], metrics left out)``: the point column, then each metric's
    column while the table stays within ``width`` columns (a metric too wide is left out,
    a narrower one after it may still fit)."""
    cols = [("point", labels)]
    used = max(len("point"), *map(len, labels))
    left = []
    for n in names:
        cells = [_cell(n, _lookup(e, n) or {}, percent) for e in points]
        head = _heading(n, percent)
        w = max(len(head), *map(len, cells))
        if used + 3 + w > width:
            left.append(n)
            continue
        cols.append((head, cells))
        used += 3 + w
    return cols, left


def _aligned(cols: list[tuple[str, list[str]]], n_rows: int) -> list[str]:
    """The lines of a plain-text table: headings, a rule, ``n_rows`` rows; columns padded to
    their widest cell and joined by `` | ``, trailing spaces cut."""
    widths = [max(len(h), *map(len, c)) for h, c in cols]

    def line(row: list[str]) -> str:
        return " | ".join(x.ljust(w) for x, w in zip(row, widths, strict=True)).rstrip()

    return ([line([h for h, _ in cols]), "-+-".join("-" * w for w in widths)]
            + [line([c[i] for _, c in cols]) for i in range(n_rows)])


def stat_cell(st: dict[str, Any], scale: float = 1.0, fmt: str = ".3g",
              n: int | None = None) -> str:
    """``"mean ± half-width"`` of a summary statistic ``{"mean", "ci95"}`` (the 95 %
    Student t interval over seeds), scaled by ``scale``. With ``n``, the interval is
    computed from ``st["std"]``, a population std (ddof 0) over ``n`` values (the
    identification tables store no interval)."""
    m = st.get("mean")
    if not isinstance(m, int | float):
        return "-"
    if n is not None:
        sd = st.get("std")
        ci = (t_quantile_975(n - 1) * sd / math.sqrt(n - 1)
              if isinstance(sd, int | float) and n > 1 else None)
    else:
        ci = st.get("ci95")
    if not isinstance(ci, int | float) or ci != ci:
        return format(m * scale, fmt)
    return f"{format(m * scale, fmt)} ± {format(ci * scale, fmt)}"


RATE = (0.0, 1.0)  #: range of a success rate (``bounds`` of :func:`seeds_cell`)


def seeds_cell(values: Any, scale: float = 1.0, fmt: str = ".3g",
               bounds: tuple[float, float] | None = None) -> str:
    """``"mean ± half-width"`` of per-seed values (95 % Student t interval of the mean),
    scaled by ``scale``. With ``bounds``, the range of the metric before scaling (e.g.
    :data:`RATE`), the interval stays in it: ``"mean [lower, upper]"`` where the t
    interval crosses the range, and ``"mean (n seeds: too few for an interval)"`` where it
    does so with fewer than :data:`vbl.stats.MIN_SEEDS_BOUNDED` seeds."""


    x = np.asarray(values, np.float64).ravel()
    m, half = mean_ci95(x)
    f = lambda v: format(v * scale, fmt)  # noqa: E731
    if half != half:
        return f(m)
    if bounds is None or bounds[0] <= m - half and m + half <= bounds[1]:
        return f"{f(m)} ± {format(half * scale, fmt)}"
    b = bounded_ci95(x, *bounds)
    if b is None:
        return f"{f(m)} ({x.size} seeds: too few for an interval)"
    return f"{f(m)} [{f(b[1])}, {f(b[2])}]"


def rate_cell(values: Any, scale: float = 1.0, fmt: str = ".3f") -> str:
    """:func:`seeds_cell` of a success rate in [0, 1] (shown times ``scale``)."""
    return seeds_cell(values, scale, fmt, RATE)


def claim(a: Any, b: Any, paired: bool = False, fmt: str = ".3g") -> str:
    """Verdict on "mean(a) > mean(b)" over seeds: "yes" when the 95 % interval of the
    difference (Welch's; with ``paired``, Student's on the per-seed differences) lies above
    0, "**no**" when it lies below, else "not resolved" with the number of seeds that would
    resolve a difference of this size. A verdict never rests on two means alone."""


    a, b = np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()
    d, h = mean_ci95(a - b) if paired else welch_ci95(a, b)
    n = min(a.size, b.size)
    diff = f"{format(d, '+' + fmt)} ± {format(h, fmt)}" if h == h else format(d, "+" + fmt)
    if h != h:
        return f"not resolved ({n} seed{'s' * (n != 1)}: no interval; {diff})"
    if d - h > 0:
        return f"yes ({diff})"
    if d + h < 0:
        return f"**no** ({diff})"
    need = seeds_to_resolve(d, h, n)
    more = (f"; about {need} seeds would resolve a difference this size" if need else "")
    return f"not resolved at {n} seeds ({diff}{more})"
