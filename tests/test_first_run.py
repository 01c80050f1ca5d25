"""benchmarks/first_run.py at a tiny size: two toy paper experiments reproduced cold, then
warm, in a fresh cache; per-run times from each manifest, metrics compared byte for byte."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import first_run  # noqa: E402
from tests.engine_helpers import write_paper_toy  # noqa: E402


def test_cold_then_warm_reproduce_rows_and_equal_metrics(tmp_path, monkeypatch):
    d = tmp_path / "exps"
    d.mkdir()
    for name in ("paper_a", "paper_b"):
        write_paper_toy(d, name, chunks=2)
    monkeypatch.setenv("VBL_EXPERIMENTS_DIR", str(d))
    monkeypatch.setenv("VBL_HOST_DEVICES", "1")
    keep = tmp_path / "kept"
    result = first_run.main(["--only", "paper_b", "--out", str(tmp_path / "fr"),
                             "--keep", str(keep)])
    for phase in ("cold", "warm"):
        runs = result[phase]["manifest"]["runs"]
        assert [r["folder"] for r in runs] == ["paper_b"]  # --only reaches the command
        assert result[phase]["cpu_s"] >= runs[0]["cpu_s"] > 0  # the command holds the run
        assert result[phase]["wall_s"] >= runs[0]["seconds"] > 0
    assert result["metrics_equal"] == {"paper_b": True}
    text = (tmp_path / "fr.md").read_text()
    assert "| paper_b |" in text and "| yes |" in text and "**cold command**" in text
    assert (tmp_path / "fr.json").exists()
    assert json.loads((keep / "reproduce.json").read_text()) == result["cold"]["manifest"]
    with pytest.raises(SystemExit, match="exists"):  # never over a kept run
        first_run.main(["--only", "paper_b", "--out", str(tmp_path / "fr2"), "--keep",
                        str(keep)])


def test_the_committed_before_line_names_its_commit_runs_and_totals():
    """The table's `before` line reads the committed measurement of the earlier code: its
    commit, its 8 runs (the PPO comparators among them) and its rounded totals."""
    before = json.loads(first_run.BEFORE.read_text())
    now = json.loads((ROOT / "benchmarks" / "results" / "first_run.json").read_text())
    text = first_run.markdown(now, before)
    line = text.strip().splitlines()[-1]
    assert line.startswith("Before: commit `da16431`") and "ppo_comparator" in line
    assert f"cold {before['cold']['wall_s']:.0f} s wall" in line
    assert f"warm {before['warm']['wall_s']:.0f} s wall" in line
    assert first_run.markdown(now).strip().splitlines()[-1].startswith("| **warm command**")
