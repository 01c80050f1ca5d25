"""What fewer seeds would have said: a finished run rebuilt from its first K seeds
(``vbl report --seeds K``), to budget a run's seeds against the claims its report
resolves. The engine keys seed ``s`` by its index alone (:func:`vbl.engine.sweep.learner_keys`),
so the first K seeds of a run are the seeds of a K-seed run of the same config: its
numbers, up to the last float bits of batched arithmetic."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

from vbl.engine.experiment import Experiment, RunResult
from vbl.engine.rebuild import load_run, results_table, run_folders
from vbl.engine.report import default_section
from vbl.engine.results import metric_arrays, point_summaries, read_metrics
from vbl.params import ParamError

__all__ = ["first_seeds", "seeds_report"]


def first_seeds(folder: str | Path, seeds: int, scratch: str | Path
                ) -> tuple[Experiment, RunResult, dict[str, Any]]:
    """``(experiment, RunResult, config.json)`` of a finished run folder, its curves, final
    metrics and summary rebuilt from ``metrics.jsonl`` for its first ``seeds`` seeds (and
    ``seeds`` in the config, so its command is that of a ``seeds``-seed run). The
    result's ``out_dir`` is ``scratch/<folder name>`` (where a report may write figures):
    the run folder is only read, and a report finds no sibling runs there."""
    folder = Path(folder)
    exp, res, spec = load_run(folder)
    if isinstance(seeds, bool) or not isinstance(seeds, int) or not 1 <= seeds <= res.seeds:
        raise ParamError(f"--seeds {seeds}: {folder} has {res.seeds} seeds; give a whole "
                          f"number from 1 to {res.seeds}")
    curves, final = metric_arrays(read_metrics(folder / "metrics.jsonl"), len(res.points))
    curves = {k: a[:, :, :seeds] for k, a in curves.items()}
    final = {k: a[:, :seeds] for k, a in final.items()}
    summary = {**res.summary, "seeds": seeds,
               "points": point_summaries(curves, final, list(res.points))}
    out_dir = Path(scratch) / folder.name
    out_dir.mkdir(parents=True, exist_ok=True)
    return exp, replace(res, out_dir=out_dir, seeds=seeds, curves=curves, final=final,
                        summary=summary, figures=[]), {**spec, "seeds": seeds}


def seeds_report(folders: list[str | Path], seeds: int,
                 link_base: str | Path | None = None) -> str:
    """Markdown: :func:`~vbl.engine.rebuild.results_table` of the runs' first ``seeds``
    seeds, then each run's report section (its claims) at ``seeds`` seeds, without
    figures and without the columns a report takes from sibling runs."""
    with tempfile.TemporaryDirectory() as scratch:
        loaded: dict[Path, tuple] = {}

        def load(folder):  # each run read once, for the table and for its section
            if folder not in loaded:
                loaded[folder] = first_seeds(folder, seeds, scratch)
            return loaded[folder]

        parts = [f"Every run rebuilt from its first {seeds} seeds.", "",
                 results_table(folders, link_base, load=load)]
        for folder in run_folders(folders):
            exp, res, _ = load(folder)
            section = (exp.report(res) if exp.report is not None
                       else default_section(res, exp.percent))
            body = "\n".join(ln for ln in section.markdown.splitlines()
                             if not ln.startswith("!["))
            parts += [f"## {Path(folder).name}, first {seeds} of its seeds", "",
                      body.strip(), ""]
    return "\n".join(parts)
