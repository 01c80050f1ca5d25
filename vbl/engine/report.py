"""``vbl reproduce``: run every paper experiment and write one ``report.md``."""

from __future__ import annotations

import os
import time
import traceback
from pathlib import Path
from typing import Any

from vbl.engine.experiment import Experiment, ReportSection, RunResult
from vbl.engine.registry import all_experiments, discover, import_errors

__all__ = ["default_section", "reproduce", "paper_experiments"]


def _fmt(st: dict[str, Any]) -> str:
    m, ci = st.get("mean"), st.get("ci95")
    if isinstance(m, int | float) and isinstance(ci, int | float):
        return f"{m:.4g} ± {ci:.2g}"
    return str(m)


def default_section(result: RunResult) -> ReportSection:
    """A table of every sweep point's last-chunk and final metrics (mean ± 95% CI)."""
    lines = []
    for entry in result.summary.get("points", []):
        label = ", ".join(f"{k}={v}" for k, v in entry["values"].items()) or "default config"
        stats = {**{f"{k} (last chunk)": v for k, v in entry.get("last_chunk", {}).items()},
                 **{f"{k} (final)": v for k, v in entry.get("final", {}).items()}}
        if not lines:
            lines += ["| point | " + " | ".join(stats) + " |", "|---" * (len(stats) + 1) + "|"]
        lines.append(f"| {label} | " + " | ".join(_fmt(v) for v in stats.values()) + " |")
    if not lines and "result" in result.summary:
        lines = ["```", str(result.summary["result"]), "```"]
    return ReportSection("\n".join(lines), tuple(result.figures))


def paper_experiments() -> dict[str, Experiment]:
    discover()
    return {n: e for n, e in all_experiments().items() if e.paper_result}


def reproduce(out: Path, *, quick: bool, quiet: bool | None, resume: bool = False,
              overwrite: bool = False, names: list[str] | None = None) -> tuple[Path, bool]:
    """Run the paper experiments into ``out/<name>/`` and write ``out/report.md``.

    Returns ``(report path, all succeeded)``. A failing experiment is reported and the
    others still run.
    """
    from vbl.engine.results import prepare_run_dir
    from vbl.engine.runner import run_experiment

    exps = paper_experiments()
    if names:
        exps = {n: exps[n] for n in names if n in exps}
    out = Path(out)
    if out.is_dir() and any(out.iterdir()) and not (resume or overwrite):
        prepare_run_dir(out, "reproduce", resume=False, overwrite=False)  # raises clearly
    out.mkdir(parents=True, exist_ok=True)
    parts = [f"# vbl reproduction report{' (--quick)' if quick else ''}", "",
             f"Generated {time.strftime('%Y-%m-%d %H:%M:%S')}. Each section puts our numbers "
             "beside the paper's; intervals are 95% confidence intervals over seeds.", ""]
    ok = True
    rows = []
    sections = []
    for name, exp in exps.items():
        t0 = time.perf_counter()
        try:
            result = run_experiment(exp, out=out / name, quick=quick, quiet=quiet,
                                    resume=resume and (out / name).exists(),
                                    overwrite=overwrite)
            section = exp.report(result) if exp.report is not None else default_section(result)
            status = "ok"
        except Exception as e:  # noqa: BLE001 - report and continue with the others
            ok = False
            status = f"failed: {type(e).__name__}: {e}"
            section = ReportSection("**failed**\n\n```\n" + "".join(
                traceback.format_exception(type(e), e, e.__traceback__))[-3000:] + "```")
            result = None
        dt = time.perf_counter() - t0
        rows.append(f"| {name} | {exp.description} | {status.splitlines()[0]} | {dt:.1f} |")
        figs = []
        for f in section.figures:
            p = Path(f)
            # A relative figure path is taken from the working directory when it exists there
            # (experiments usually return run_dir / name with a relative run_dir), else from
            # the run folder.
            if not p.is_absolute() and not p.exists() and result is not None:
                p = result.out_dir / p
            figs.append(f"![{p.stem}]({os.path.relpath(p.absolute(), out.absolute())})")
        sections += [f"## {name}", "", exp.description, "", section.markdown, "",
                     *(f + "\n" for f in figs), ""]
    for path, err in import_errors().items():
        rows.append(f"| {Path(path).stem} | (script failed to import) | failed: {err} | |")
        ok = False
    parts += ["| experiment | what | status | time (s) |", "|---|---|---|---|", *rows, "",
              *sections]
    report = out / "report.md"
    report.write_text("\n".join(parts) + "\n")
    return report, ok
