"""The README's generated tables: the results table is `vbl report` over the committed run
folders its marker names, the benchmark table is each benchmark's headline figure read from
benchmarks/results/*.json (what `vbl bench` prints). Neither can be typed by hand.

Regenerate both after a new run folder or benchmark result:

    python tests/test_readme_results.py
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
REPORT = re.compile(r"(<!-- vbl report ([^>]*?) -->\n)(.*?)(<!-- /vbl report -->)", re.S)
BENCH = re.compile(r"(<!-- vbl bench headlines -->\n)(.*?)(<!-- /vbl bench -->)", re.S)


def report_folders(text: str) -> list[str]:
    m = REPORT.search(text)
    assert m, "README.md has no <!-- vbl report RUN_DIR ... --> ... <!-- /vbl report --> block"
    return m.group(2).split()


def results_block(folders: list[str]) -> str:
    from vbl.engine.report import results_table

    return results_table([ROOT / f for f in folders], link_base=ROOT)


def bench_block() -> str:
    """One row per benchmark: its headline figure, target and verdict (as `vbl bench`
    prints them) and a link to its committed results."""
    from vbl.engine.bench import TARGETS, _number, benchmarks

    results = ROOT / "benchmarks" / "results"
    lines = ["| benchmark | headline figure | target | verdict | results |",
             "|---|---|---|---|---|"]
    for name in sorted(set(TARGETS) | set(benchmarks(ROOT / "benchmarks"))):
        t, path = TARGETS.get(name), results / f"{name}.json"
        md = results / f"{name}.md"
        link = f"[{md.name}](benchmarks/results/{md.name})" if md.exists() else "-"
        if t is None or not path.exists():
            lines.append(f"| {name} | no committed result (`vbl bench {name} --out "
                         f"benchmarks/results`) | | | {link} |")
            continue
        value, what = t.figure(json.loads(path.read_text()))
        if t.goal is None:
            target, verdict = "none stated", "-"
        else:
            ok = value >= t.goal if t.higher else value <= t.goal
            target = f"{'>=' if t.higher else '<='} {_number(t.goal)}"
            verdict = "met" if ok else "**not met**"
        lines.append(f"| {name} | {_number(float(value))} {what} | {target} | {verdict} | "
                     f"{link} |")
    return "\n".join(lines) + "\n"


def regenerate(text: str) -> str:
    folders = report_folders(text)
    text = REPORT.sub(lambda m: m.group(1) + results_block(folders) + m.group(4), text)
    return BENCH.sub(lambda m: m.group(1) + bench_block() + m.group(3), text)


def test_readme_results_table_is_vbl_report_of_the_committed_run_folders():
    text = README.read_text()
    folders = report_folders(text)
    assert all((ROOT / f / "config.json").exists() for f in folders), folders
    assert REPORT.search(text).group(3) == results_block(folders), (
        "README.md's results table differs from `vbl report` over its run folders; "
        "regenerate: python tests/test_readme_results.py")


def test_readme_benchmark_table_is_read_from_the_committed_results():
    m = BENCH.search(README.read_text())
    assert m, "README.md has no <!-- vbl bench headlines --> ... <!-- /vbl bench --> block"
    assert m.group(2) == bench_block(), (
        "README.md's benchmark table differs from benchmarks/results/*.json; regenerate: "
        "python tests/test_readme_results.py")


def test_every_paper_experiment_has_a_row_in_the_readme():
    from vbl.engine.report import paper_experiments

    reported = {json.loads((ROOT / f / "config.json").read_text())["experiment"]
                for f in report_folders(README.read_text())}
    missing = {n for n, e in paper_experiments().items() if e.paper_rows is not None}
    assert missing <= reported, f"paper experiments without a README row: {missing - reported}"


def test_report_commands_rebuild_the_recorded_config(tmp_path):
    """A fresh run folder: the command `vbl report` rebuilds is the one that was run."""
    from vbl.engine import get, run_experiment
    from vbl.engine.report import load_run, run_command

    exp = get("toy_bandit")
    run_experiment(exp, sets={"agent.epsilon": 0.05, "env.num_arms": 4},
                   sweep={"agent.learning_rate": [0.1, 0.5]}, seeds=3, base_seed=7,
                   out=tmp_path / "run", quick=True, quiet=True, plots=False)
    exp, _, spec = load_run(tmp_path / "run")
    command, unrecorded = run_command(exp, spec)
    assert command == ("vbl run toy_bandit --quick --seeds 3 --seed 7 --sweep "
                       "agent.learning_rate=0.1,0.5 --set env.num_arms=4 --set "
                       "agent.epsilon=0.05")
    assert unrecorded == []


@pytest.mark.parametrize("folder, command, unrecorded", [
    ("table2_full", "vbl run table2_shoot_pass --set cva.keep_beyond_order=false --set "
     "cva.n_used_objects=4,4,4 --set cva.quantizer.group_codes=16,8,8 --set q.discount=0.95 "
     "--set q.learning_rate=0.5", False),
    # fig5_cells also trained the grid baseline with synchronous macro actions
    ("fig5_cells", "vbl run fig5_action_based --preset construction_only --set "
     "baseline.agent.learning_rate=0.1 --set baseline.agent.exploration.transition_steps=500.0 "
     "--set baseline.agent.macro.mode=sync --set baseline.agent.lem.window=100 --set "
     "baseline.agent.chunk_steps=100 --set baseline.train.eval_steps=400", True),
    ("table1", "vbl run table1_identification", False),
    # swept with an older default of the swept path (0.5) recorded as its base value
    ("table2_lr_sweep", "vbl run table2_shoot_pass --sweep q.learning_rate=0.1,0.25,0.5 "
     "--set q.discount=0.95", False),
])
def test_commands_of_older_folders_use_the_legacy_values(folder, command, unrecorded):
    """Parameters added after a folder was written take the experiment's legacy_values
    (fig5_cells predates the refinement: refine.iterations=0); the others are named."""
    from vbl.engine.report import load_run, run_command

    exp, _, spec = load_run(ROOT / "docs/results" / folder)
    got, missing = run_command(exp, spec)
    assert got == command
    assert bool(missing) == unrecorded, missing


def _unknown_experiment(p: Path) -> Path:
    (p / "config.json").write_text('{"experiment": "nope", "config": {}}')
    (p / "summary.json").write_text("{}")
    return p


@pytest.mark.parametrize("make, message", [
    (lambda p: p, "is not a finished run folder"),
    (lambda p: p / "missing", "is not a run folder"),
    (_unknown_experiment, "unknown experiment 'nope'"),
])
def test_report_errors_are_one_line(tmp_path, capsys, make, message):
    from vbl.cli import main

    folder = make(tmp_path)
    assert main(["report", str(folder)]) == 1
    err = [x for x in capsys.readouterr().err.splitlines() if x.startswith("vbl:")]
    assert len(err) == 1 and err[0].startswith("vbl: error: ") and message in err[0], err


def test_report_of_an_experiment_without_paper_rows_says_so(tmp_path, capsys):
    from vbl.cli import main
    from vbl.engine import get, run_experiment

    run_experiment(get("toy_bandit"), seeds=2, out=tmp_path / "run", quick=True, quiet=True,
                   plots=False)
    assert main(["report", str(tmp_path / "run")]) == 1
    assert "declares no paper rows" in capsys.readouterr().err


def test_report_out_writes_links_relative_to_the_file(tmp_path):
    from vbl.cli import main

    out = tmp_path / "sub" / "results.md"
    out.parent.mkdir()
    assert main(["report", str(ROOT / "docs/results/table2_lr025_g099"), "--out", str(out)]) == 0
    text = out.read_text()
    assert "`vbl run table2_shoot_pass`" in text and "| 78.5 |" in text
    link = re.search(r"\[table2_lr025_g099\]\(([^)]+)\)", text).group(1)
    assert (out.parent / link).resolve() == ROOT / "docs/results/table2_lr025_g099/report.md"


if __name__ == "__main__":
    new = regenerate(README.read_text())
    README.write_text(new)
    print(f"{README.relative_to(ROOT)}: tables regenerated", file=sys.stderr)
