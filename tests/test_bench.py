"""``vbl bench``'s own logic on a fake benchmark folder (vbl/engine/bench.py): which scripts
are benchmarks, the headline verdicts against their targets, where results go and what a
failing script reports. The real benchmarks run in tests/test_benchmarks_quick.py."""

from __future__ import annotations

import json
import math

import pytest

from vbl.engine import bench
from vbl.engine.bench import TARGETS, Target, benchmarks, headline, run_benchmarks
from vbl.params import ParamError

WRITES = """import json, pathlib, sys
if __name__ == "__main__":
    here = pathlib.Path(__file__).resolve().parent
    (here / "results" / "{name}.json").write_text(json.dumps({{"quick": "--quick" in sys.argv,
                                                            "rows": [{{"x": {value}}}],
                                                            "ran_from": str(here)}}))
    sys.exit({code})
"""


@pytest.fixture
def fake_bench(tmp_path, monkeypatch):
    """A benchmark folder: ``fast`` (exits 0, figure 3.0), ``broken`` (writes, exits 1), a
    helper module without __main__ and a private script; with committed results."""
    src = tmp_path / "src" / "benchmarks"
    (src / "results").mkdir(parents=True)
    (src / "fast.py").write_text(WRITES.format(name="fast", value=3.0, code=0))
    (src / "broken.py").write_text(WRITES.format(name="broken", value=1.0, code=1))
    (src / "hardware.py").write_text("X = 1\n")
    (src / "_private.py").write_text('if __name__ == "__main__":\n    pass\n')
    (src / "results" / "fast.json").write_text('"committed"')
    monkeypatch.setenv("VBL_BENCH_DIR", str(src))
    monkeypatch.setitem(TARGETS, "fast", Target(lambda r: (r["rows"][0]["x"], "things/s"), 2.0))
    return src


def test_only_public_scripts_with_a_main_block_are_benchmarks(fake_bench):
    assert bench.bench_dir() == fake_bench.resolve()
    assert list(benchmarks()) == ["broken", "fast"]


def test_results_go_to_out_and_the_committed_results_stay(fake_bench, tmp_path):
    out = tmp_path / "out"
    lines = []
    failed = run_benchmarks(["fast", "broken"], out, quick=True, echo=lines.append)
    assert failed == ["broken"]
    got = json.loads((out / "fast.json").read_text())
    assert got["quick"] is True and got["ran_from"] != str(fake_bench.resolve())  # a copy
    assert (fake_bench / "results" / "fast.json").read_text() == '"committed"'
    assert not (out / ".scripts").exists()
    assert "  fast: 3 things/s; target >= 2: met" in lines
    assert "  broken: failed" in lines
    with pytest.raises(ParamError, match=r"unknown benchmark\(s\) \['nope'\]"):
        run_benchmarks(["nope"], out, quick=True, echo=lines.append)


def test_out_as_the_results_folder_runs_in_place(fake_bench):
    run_benchmarks(["fast"], fake_bench / "results", quick=False, echo=lambda s: None)
    got = json.loads((fake_bench / "results" / "fast.json").read_text())
    assert got["quick"] is False and got["ran_from"] == str(fake_bench.resolve())


def _write(tmp_path, name, value):
    (tmp_path / f"{name}.json").write_text(json.dumps({"rows": [{"x": value}]}))


@pytest.mark.parametrize("value, higher, goal, verdict", [
    (2.0, True, 2.0, "target >= 2: met"), (1.99, True, 2.0, "target >= 2: not met"),
    (2.0, False, 2.0, "target <= 2: met"), (2.01, False, 2.0, "target <= 2: not met"),
    (math.nan, False, 2.0, "target <= 2: not met"), (math.nan, True, 2.0, "not met"),
    (5.0, True, None, "target: none stated")])
def test_the_verdict_compares_the_figure_with_its_target(tmp_path, monkeypatch, value, higher,
                                                         goal, verdict):
    monkeypatch.setitem(TARGETS, "t", Target(lambda r: (r["rows"][0]["x"], "u"), goal, higher))
    _write(tmp_path, "t", value)
    assert headline("t", tmp_path).endswith(verdict)


def test_numbers_are_shown_with_thousands_separators_or_three_digits(tmp_path, monkeypatch):
    monkeypatch.setitem(TARGETS, "t", Target(lambda r: (r["rows"][0]["x"], "u"), 1e6))
    _write(tmp_path, "t", 1234567.8)
    assert headline("t", tmp_path) == "t: 1,234,568 u; target >= 1,000,000: met"
    for value, shown in ((1000.0, "1,000"), (5000.0, "5,000"), (999.4, "999")):
        _write(tmp_path, "t", value)
        assert headline("t", tmp_path).startswith(f"t: {shown} u;")
    _write(tmp_path, "t", 0.012345)
    assert headline("t", tmp_path).startswith("t: 0.0123 u;")


def test_a_missing_or_unreadable_result_is_said_so(tmp_path, monkeypatch):
    monkeypatch.setitem(TARGETS, "t", Target(lambda r: (r["rows"][0]["x"], "u"), 1.0))
    assert headline("t", tmp_path) == "t: no figure read (t.json missing)"
    (tmp_path / "t.json").write_text("{not json")
    assert headline("t", tmp_path) == "t: no figure read (t.json missing)"
    (tmp_path / "t.json").write_text('{"other": 1}')
    assert headline("t", tmp_path) == "t: results in t.json (headline figure not found)"
    _write(tmp_path, "u", 1.0)
    assert headline("u", tmp_path) == "u: no figure read (u.json kept)"  # no target
