"""The generated blocks of the README and the findings notes: results tables are `vbl
report` over the committed `vbl reproduce` run (docs/results/reproduce), the runs table is
read from the committed runs' reproduce.json (full and quick scale), the benchmark table is
each benchmark's headline figure read from benchmarks/results/*.json (what `vbl bench`
prints). None can be typed by hand, and the committed runs must be of today's configs.

Regenerate every block after a new reproduce run or benchmark result:

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
FULL = "docs/results/reproduce"  #: the committed full-scale `vbl reproduce` run
QUICK = "docs/results/reproduce-quick"  #: the committed `vbl reproduce --quick` run
REPORT = re.compile(r"(<!-- vbl report ([^>]*?) -->\n)(.*?)(<!-- /vbl report -->)", re.S)
RUNS = re.compile(r"(<!-- vbl reproduce runs -->\n)(.*?)(<!-- /vbl reproduce runs -->)", re.S)
BENCH = re.compile(r"(<!-- vbl bench headlines -->\n)(.*?)(<!-- /vbl bench -->)", re.S)
COMMAND = re.compile(r"`vbl run [a-z0-9_]+( --preset [a-z0-9_]+)?`")


def report_folders(text: str) -> list[str]:
    m = REPORT.search(text)
    assert m, "no <!-- vbl report RUN_DIR ... --> ... <!-- /vbl report --> block"
    return m.group(2).split()


def results_block(folders: list[str], base: Path = ROOT) -> str:
    from vbl.engine.rebuild import results_table

    return results_table([ROOT / f for f in folders], link_base=base)


def _manifest(folder: str) -> dict:
    return json.loads((ROOT / folder / "reproduce.json").read_text())


def runs_block() -> str:
    """The committed runs' machine, code and per-run wall time and peak memory, full and
    quick scale, and the quick runs' CPU time (from each run's reproduce.json)."""
    full, quick = _manifest(FULL), _manifest(QUICK)
    q = {r["folder"]: r for r in quick["runs"]}
    lines = [f"Full scale: `vbl reproduce` on {full['machine']}, {full['wall_s'] / 60:.0f} min "
             f"wall in {full['workers']} worker processes (load average "
             f"{full['load_average'][0]:g} at the start), code `{full['commit'][:12]}`. "
             f"Quick scale: `vbl reproduce --quick` on {quick['machine']}, "
             f"{quick['wall_s']:.0f} s wall (load average {quick['load_average'][0]:g} at the "
             f"start), code `{quick['commit'][:12]}`.", "",
             "| run | full: wall time | full: peak memory | quick: wall time | quick: CPU "
             "time | quick: peak memory |", "|---|---|---|---|---|---|"]
    for r in full["runs"]:
        rq = q.get(r["folder"])
        cpu = f"{rq['cpu_s']:.0f} s" if rq and rq.get("cpu_s") is not None else "-"
        quick_cells = (f"{rq['seconds']:.0f} s | {cpu} | {rq['peak_rss_mb'] / 1024:.1f} GiB"
                       if rq else "full run only | - | -")
        lines.append(f"| {r['folder']} | {r['seconds'] / 60:.1f} min | "
                     f"{r['peak_rss_mb'] / 1024:.1f} GiB | {quick_cells} |")
    return "\n".join(lines) + "\n"


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


FINDINGS = sorted((ROOT / "docs" / "findings").glob("*.md"))


def regenerate(text: str, base: Path = ROOT) -> str:
    """``text`` with every generated block made again: results tables (links relative to
    ``base``), the runs table and the benchmark table."""
    text = REPORT.sub(lambda m: m.group(1) + results_block(m.group(2).split(), base)
                      + m.group(4), text)
    text = RUNS.sub(lambda m: m.group(1) + runs_block() + m.group(3), text)
    return BENCH.sub(lambda m: m.group(1) + bench_block() + m.group(3), text)


def test_readme_results_table_is_vbl_report_of_the_committed_reproduce_run():
    text = README.read_text()
    assert report_folders(text) == [FULL]
    assert REPORT.search(text).group(3) == results_block([FULL]), (
        "README.md's results table differs from `vbl report` over the committed reproduce "
        "run; regenerate: python tests/test_readme_results.py")


def test_vbl_report_of_the_reproduce_folder_equals_the_readme_table(capsys):
    from vbl.cli import main

    assert main(["report", str(ROOT / FULL)]) == 0
    printed = capsys.readouterr().out
    assert printed.splitlines()[2:] and len(printed.splitlines()) == len(
        REPORT.search(README.read_text()).group(3).splitlines())


def test_every_readme_row_is_a_default_or_a_named_preset():
    block = REPORT.search(README.read_text()).group(3)
    commands = [c for c in (row.split("|")[6].strip() for row in block.splitlines()[2:]) if c]
    assert commands and all(COMMAND.fullmatch(c) for c in commands), commands


def test_generated_blocks_of_readme_and_findings_are_current():
    for path in [README, *FINDINGS]:
        text = path.read_text()
        assert regenerate(text, path.parent) == text, (
            f"{path.relative_to(ROOT)}: a generated block is out of date; regenerate: "
            "python tests/test_readme_results.py")


@pytest.mark.parametrize("folder, quick", [(FULL, False), (QUICK, True)])
def test_the_committed_reproduce_runs_are_todays_published_configs(folder, quick):
    """Every published result ran, at its scale, with the config today's code resolves for
    it (a changed default, preset or quick override fails here until the runs are redone),
    and every run finished."""
    from vbl.engine.registry import source_file
    from vbl.engine.reproduce import paper_experiments, reproduce_jobs
    from vbl.engine.runner import resolve

    manifest = _manifest(folder)
    assert manifest["quick"] is quick
    builtin = (ROOT / "experiments").resolve()  # other tests register paper toys
    exps = {n: e for n, e in paper_experiments().items()
            if source_file(n) and Path(source_file(n)).resolve().parent == builtin}
    jobs = reproduce_jobs(exps, quick)
    assert [r["folder"] for r in manifest["runs"]] == [j.folder for j in jobs]
    assert all(r["status"] == "ok" for r in manifest["runs"]), manifest["runs"]
    assert not manifest["commit"].endswith("+dirty") and manifest["commit"] != "unknown"
    for j in jobs:
        spec = json.loads((ROOT / folder / j.folder / "config.json").read_text())
        *_, today = resolve(exps[j.name], quick=quick, preset=j.preset)
        assert spec == today, f"{folder}/{j.folder} ran another config than today's"


def test_report_commands_rebuild_the_recorded_config(tmp_path):
    """A fresh run folder: the command `vbl report` rebuilds is the one that was run."""
    from vbl.engine import get, run_experiment
    from vbl.engine.rebuild import load_run, run_command

    exp = get("toy_bandit")
    run_experiment(exp, sets={"agent.epsilon": 0.05, "env.num_arms": 4},
                   sweep={"agent.learning_rate": [0.1, 0.5]}, seeds=3, base_seed=7,
                   out=tmp_path / "run", quick=True, quiet=True, plots=False)
    exp, _, spec = load_run(tmp_path / "run")
    assert run_command(exp, spec) == (
        "vbl run toy_bandit --quick --seeds 3 --seed 7 --sweep agent.learning_rate=0.1,0.5 "
        "--set env.num_arms=4 --set agent.epsilon=0.05")


def _unknown_experiment(p: Path) -> Path:
    (p / "config.json").write_text('{"format": 2, "experiment": "nope", "config": {}}')
    (p / "summary.json").write_text("{}")
    return p


@pytest.mark.parametrize("make, message", [
    (lambda p: p, "is not a finished run folder"),
    (lambda p: p / "missing", "is not a run folder"),
    (_unknown_experiment, "unknown experiment 'nope'"),
])
def test_report_errors_are_one_line(tmp_path, capsys, make, message):
    """A bad folder is one line and exit 2, as from vbl render, export and plot."""
    from vbl.cli import main

    folder = make(tmp_path)
    commands = [["report"], ["render", "--out", str(tmp_path / "v.gif")], ["export"]]
    for command in commands[:2] if make is _unknown_experiment else commands:
        # (export reads any run folder's rows, whatever its experiment)
        code = main([*command, str(folder)])
        err = [x for x in capsys.readouterr().err.splitlines() if x.startswith("vbl:")]
        assert code == 2 and len(err) == 1 and err[0].startswith("vbl: error: "), \
            (command, code, err)
        assert message in err[0] or command[0] != "report", err


def test_report_of_an_experiment_without_paper_rows_says_so(tmp_path, capsys):
    from vbl.cli import main
    from vbl.engine import get, run_experiment

    run_experiment(get("toy_bandit"), seeds=2, out=tmp_path / "run", quick=True, quiet=True,
                   plots=False)
    assert main(["report", str(tmp_path / "run")]) == 2  # bad input, as every bad folder
    assert "declares no paper rows" in capsys.readouterr().err


def test_report_out_writes_links_relative_to_the_file(tmp_path):
    from vbl.cli import main

    out = tmp_path / "sub" / "results.md"
    out.parent.mkdir()
    run = ROOT / FULL / "table2_shoot_pass"
    assert main(["report", str(run), "--out", str(out)]) == 0
    text = out.read_text()
    assert "`vbl run table2_shoot_pass`" in text and "| 78.5 |" in text
    link = re.search(r"\[table2_shoot_pass\]\(([^)]+)\)", text).group(1)
    assert (out.parent / link).resolve() == run / "report.md"


if __name__ == "__main__":
    for path in [README, *FINDINGS]:
        path.write_text(regenerate(path.read_text(), path.parent))
        print(f"{path.relative_to(ROOT)}: generated blocks regenerated", file=sys.stderr)
