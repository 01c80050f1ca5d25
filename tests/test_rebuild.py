"""Reading run folders back (vbl/engine/rebuild.py) without running: command-line values,
the flags of a rebuilt command, a reproduce folder's runs in order, and ``vbl report``'s
table (its links, and the seeds and command on each run's first row)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from vbl.engine import rebuild
from vbl.engine.errors import EngineError
from vbl.engine.experiment import PaperRow


@pytest.mark.parametrize("value, text", [(True, "true"), ((1, 2.5), "1,2.5"), ((3,), "(3)"),
                                         (("a", "b"), "(a,b)"), ([1.5, True], "(1.5,true)"),
                                         (0.1, "0.1")])
def test_command_line_values(value, text):
    assert rebuild._cli_value(value) == text


def test_a_rebuilt_command_names_only_what_differs_from_the_defaults():
    exp = SimpleNamespace(name="demo", seeds=8, quick_seeds=2)
    flags = rebuild._run_flags
    assert flags(exp, False, None, 8, 0) == ["vbl", "run", "demo"]
    assert flags(exp, True, None, 2, 0) == ["vbl", "run", "demo", "--quick"]
    assert flags(exp, True, "small", 8, 3) == ["vbl", "run", "demo", "--quick", "--preset",
                                               "small", "--seeds", "8", "--seed", "3"]
    exp = SimpleNamespace(name="demo", seeds=8, quick_seeds=None)
    assert flags(exp, True, None, 8, 0) == ["vbl", "run", "demo", "--quick"]


def test_a_reproduce_folder_stands_for_its_runs_in_the_order_they_ran(tmp_path):
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / rebuild.REPRODUCE_MANIFEST).write_text(json.dumps(
        {"runs": [{"folder": "b"}, {"folder": "a"}]}))
    assert rebuild.run_folders([tmp_path / "x", rep]) == [tmp_path / "x", rep / "b", rep / "a"]


def test_report_table_shows_seeds_link_and_command_on_each_runs_first_row(tmp_path,
                                                                          monkeypatch):
    rows = [PaperRow("Table 1, %", "16", "15.2 ± 1.1"), PaperRow("Table 1, s", "3", "2.9")]
    exp = SimpleNamespace(name="demo", paper_rows=lambda result: rows)
    runs = tmp_path / "runs"
    for name in ("run [1]", "two"):
        (runs / name).mkdir(parents=True)
    (runs / "two" / "report.md").write_text("#")

    def load(folder):
        return exp, SimpleNamespace(seeds=5), {"name": folder.name}

    monkeypatch.setattr(rebuild, "run_command", lambda exp, spec: f"vbl run {spec['name']}")
    table = rebuild.results_table([runs / "run [1]", runs / "two"], tmp_path, load=load)
    lines = table.splitlines()
    assert lines[2] == ("| Table 1, % | 16 | 15.2 ± 1.1 | 5 | [run \\[1\\]](runs/run%20%5B1%5D/)"
                        " | `vbl run run [1]` |")
    assert lines[3] == "| Table 1, s | 3 | 2.9 |  |  |  |"
    assert lines[4].endswith("| 5 | [two](runs/two/report.md) | `vbl run two` |")
    assert len(lines) == 6 and table.endswith("\n")
    exp.paper_rows = None
    with pytest.raises(EngineError, match="declares no paper rows"):
        rebuild.results_table([runs / "two"], tmp_path, load=load)
