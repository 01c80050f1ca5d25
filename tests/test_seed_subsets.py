"""`vbl report --seeds K` (vbl.engine.seed_subsets): a run rebuilt from its first K seeds
equals a K-seed run of the same config; K = all seeds rebuilds the committed report; the
run folder is only read; a bad K is one line, exit 2."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from tests.engine_helpers import REPO, TINY_SETS, toy_experiment
from vbl.engine.rebuild import load_run
from vbl.engine.runner import run_experiment
from vbl.engine.seed_subsets import first_seeds, seeds_report
from vbl.params import ParamError

RESULTS = REPO / "docs" / "results" / "reproduce"
SETS = {**TINY_SETS, "train.num_chunks": 4}
SWEEP = {"agent.learning_rate": [0.1, 0.5]}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seeds")
    registered = toy_experiment(tmp)
    toy = next(registered)
    four = run_experiment(toy, sets=SETS, sweep=SWEEP, seeds=4, out=tmp / "four",
                          quiet=True, plots=False)
    two = run_experiment(toy, sets=SETS, sweep=SWEEP, seeds=2, out=tmp / "two",
                         quiet=True, plots=False)
    next(registered, None)  # the experiments folder as it was (the committed runs' tests)
    return four, two, tmp


def _close(a, b):
    """Nested JSON-like values equal, floats to float32 rounding."""
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _close(a[k], b[k])
    elif isinstance(a, list) and a and isinstance(a[0], dict):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _close(x, y)
    elif isinstance(a, list | float):
        np.testing.assert_allclose(np.asarray(a, float), np.asarray(b, float), rtol=1e-6,
                                   atol=1e-9, equal_nan=True)
    else:
        assert a == b


def test_first_seeds_of_a_run_are_the_run_with_fewer_seeds(runs):
    four, two, tmp = runs
    _, res, spec = first_seeds(four.out_dir, 2, tmp / "scratch")
    assert res.seeds == 2 and spec["seeds"] == 2 and res.final and res.curves
    for k, a in two.final.items():
        np.testing.assert_allclose(res.final[k], a, rtol=1e-6)
    for k, a in two.curves.items():
        np.testing.assert_allclose(res.curves[k], a, rtol=1e-6, equal_nan=True)
    _close(res.summary["points"], json.loads((two.out_dir / "summary.json").read_text())
           ["points"])


def test_all_seeds_rebuild_the_summary_and_leave_the_folder_as_it_was(runs):
    four, _, tmp = runs
    before = {p.name: p.stat().st_mtime_ns for p in four.out_dir.iterdir()}
    _, res, _ = first_seeds(four.out_dir, 4, tmp / "scratch")
    assert res.out_dir != four.out_dir
    _close(res.summary, json.loads((four.out_dir / "summary.json").read_text()))
    assert {p.name: p.stat().st_mtime_ns for p in four.out_dir.iterdir()} == before


@pytest.mark.parametrize("k", [0, 5, True])
def test_a_seed_count_outside_the_run_is_refused(runs, k):
    four, _, tmp = runs
    with pytest.raises(ParamError, match="give a whole number from 1 to 4"):
        first_seeds(four.out_dir, k, tmp / "scratch")


def _body(markdown: str) -> list[str]:
    return [ln for ln in markdown.splitlines() if ln.strip() and not ln.startswith("![")]


@pytest.mark.parametrize("name", ["table1_identification", "table2_shoot_pass"])
def test_all_seeds_of_a_committed_run_give_its_committed_report(name):
    folder = RESULTS / name
    exp, res, _ = load_run(folder)
    text = seeds_report([folder], res.seeds)
    committed = _body((folder / "report.md").read_text())[2:]  # after its title, description
    section = text.split(f"## {name}, first {res.seeds} of its seeds")[1]
    assert _body(section) == committed
    assert f"`vbl run {name}`" in text  # all seeds: the folder's own command


def test_half_the_seeds_of_table2_keep_its_verdicts_but_not_its_monte_carlo_ones():
    # docs/findings/reproduce_budget.md: what Table 2's 16 seeds buy
    text = seeds_report([RESULTS / "table2_shoot_pass"], 8)
    assert "`vbl run table2_shoot_pass --seeds 8`" in text and "8 seeds per row" in text
    assert any(ln.startswith("| shoot | **no**") for ln in text.splitlines())  # CVA - current
    mc = seeds_report([RESULTS / "table2_shoot_pass-monte_carlo"], 8)
    assert any(ln.startswith("| pass | not resolved at 8 seeds") for ln in mc.splitlines())


BUDGET = REPO / "docs" / "findings" / "reproduce_budget.md"
FOLDERS = {"table2_shoot_pass, Monte Carlo": "table2_shoot_pass-monte_carlo",
           "table3_noisy, pixels": "table3_noisy-pixels"}
VERDICT = re.compile(r"not resolved at \d+ seeds|\byes\b|\bno\b(?= \(|,|\*\*)|above 0|below 0")


def _verdicts(folder: Path, seeds: int) -> list[str]:
    section = seeds_report([folder], seeds).split("## ", 1)[1]
    return [re.sub(r"\d+", "N", v) for v in VERDICT.findall(section)]


def _budget_rows() -> list[tuple[str, int, int, str]]:
    text = BUDGET.read_text().split("## Would fewer seeds do?", 1)[1]
    rows = [r.split("|")[1:-1] for r in text.splitlines() if re.match(r"\| \w", r)]
    return [(n.strip(), int(s), int(k), v.strip()) for n, s, k, v in rows[1:]]


@pytest.mark.parametrize("name, seeds, k, says", _budget_rows())
def test_the_budget_notes_verdicts_at_fewer_seeds_are_the_committed_runs(name, seeds, k,
                                                                         says):
    name, quick = name.removesuffix(" --quick"), name.endswith(" --quick")
    folder = (RESULTS.with_name("reproduce-quick") if quick else RESULTS) / FOLDERS.get(name,
                                                                                      name)
    assert load_run(folder)[1].seeds == seeds
    full, fewer = _verdicts(folder, seeds), _verdicts(folder, k)
    assert len(full) == len(fewer)
    changed = sum(a != b for a, b in zip(full, fewer, strict=True))
    if says.startswith("none of"):
        assert changed == 0 and int(says.split()[2]) == len(full)
    elif not says.startswith("(no claim"):
        assert changed > 0
