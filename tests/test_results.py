"""A run folder's result files (vbl/engine/results.py): JSON without NaN, seed statistics,
``metrics.jsonl`` read back, cut back to a checkpoint, and turned into curves and a
summary.

Truths: SciPy's Student t interval, NumPy's std, hand-written files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats as sps

from vbl.engine.errors import EngineError
from vbl.engine.results import (
    MetricsLog,
    metric_arrays,
    point_summaries,
    read_metrics,
    seed_stats,
    write_json,
)


def test_json_files_hold_null_for_nan_and_infinity(tmp_path):
    f = tmp_path / "s.json"
    write_json(f, {"a": np.float32(np.inf), "b": np.array([1.5, np.nan, -np.inf]),
                   "c": np.int64(3)})
    text = f.read_text()
    assert json.loads(text, parse_constant=lambda c: pytest.fail(c)) == {
        "a": None, "b": [1.5, None, None], "c": 3}
    assert not (tmp_path / "s.json.tmp").exists()


def test_plain_python_nan_and_infinity_are_null_too(tmp_path):
    """Python floats and np.float64 (a float subclass) never reach the NumPy conversion:
    they too are written as null, in JSON files and in metrics lines."""
    strict = {"parse_constant": lambda c: pytest.fail(c)}
    f = tmp_path / "s.json"
    write_json(f, {"a": float("nan"), "b": [1.0, float("inf"), (np.float64("-inf"), 2)],
                   "c": {"d": np.float64("nan"), "e": True}})
    assert json.loads(f.read_text(), **strict) == {"a": None, "b": [1.0, None, [None, 2]],
                                                   "c": {"d": None, "e": True}}
    log = MetricsLog(tmp_path / "metrics.jsonl")
    log.append([{"step": 1, "x": float("nan")}, {"step": 2, "x": 0.5}])
    lines = (tmp_path / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(x, **strict) for x in lines] == [{"step": 1, "x": None},
                                                         {"step": 2, "x": 0.5}]


def test_seed_stats_is_the_sample_std_and_students_interval():
    x = np.array([0.2, 0.5, 0.9, 0.4])
    st = seed_stats(x)
    assert st["mean"] == pytest.approx(x.mean()) and st["std"] == pytest.approx(x.std(ddof=1))
    assert st["ci95"] == pytest.approx(sps.t.ppf(0.975, 3) * sps.sem(x), rel=1e-5)
    assert st["per_seed"] == x.tolist()
    one = seed_stats([0.7])
    assert (one["mean"], one["std"], one["ci95"]) == (0.7, 0.0, None)


def _row(step, chunk, point=0, per_seed=(1.0, 2.0)):
    return {"step": step, "chunk": chunk, "point": point,
            "metrics": {"m": {"per_seed": list(per_seed)}}}


def test_truncate_keeps_the_rows_up_to_the_checkpoint_step(tmp_path):
    log = MetricsLog(tmp_path / "metrics.jsonl")
    log.append([_row(s, s - 1) for s in (1, 2, 3, 4)])
    assert log.truncate_after(2) == 2
    assert [r["step"] for r in read_metrics(log.path)] == [1, 2]
    MetricsLog(tmp_path / "off.jsonl", enabled=False).append([_row(1, 0)])
    assert not (tmp_path / "off.jsonl").exists()


def test_a_torn_last_line_is_ignored_a_damaged_middle_line_is_an_error(tmp_path):
    f = tmp_path / "metrics.jsonl"
    good = json.dumps(_row(1, 0)) + "\n"
    f.write_text(good + '{"step": 2, "chu')
    assert [r["step"] for r in read_metrics(f)] == [1]
    for bad in ('{"step": 2, "chu\n', '{"step": true, "chunk": 1}\n', "[1, 2]\n"):
        f.write_text(good + bad + good)
        with pytest.raises(EngineError, match="line 2 is not a metrics row"):
            read_metrics(f)
    assert read_metrics(tmp_path / "none.jsonl") == []


def test_curves_have_a_chunk_per_logged_chunk_and_nan_where_a_row_is_missing():
    rows = [_row(1, 0, 0), _row(2, 2, 0, (5.0, 6.0)), _row(3, 0, 1),
            {"step": 4, "chunk": "final", "point": 1, "metrics": {"f": {"per_seed": [9.0]}}}]
    curves, final = metric_arrays(rows, points=2)
    assert curves["m"].shape == (2, 3, 2)  # chunks 0..2
    np.testing.assert_array_equal(curves["m"][0, 2], [5.0, 6.0])
    assert np.isnan(curves["m"][0, 1]).all() and np.isnan(curves["m"][1, 1:]).all()
    np.testing.assert_array_equal(final["f"], [[np.nan], [9.0]])
    assert metric_arrays(rows, points=2, chunks=5)[0]["m"].shape == (2, 5, 2)


def test_a_points_summary_takes_its_last_logged_chunk():
    m = np.full((2, 4, 2), np.nan)
    m[0, :3] = [[1.0, 1.0], [2.0, 2.0], [3.0, np.nan]]  # chunk 2 half logged, 3 not at all
    m[1, 0] = [7.0, 9.0]
    out = point_summaries({"m": m}, {"f": np.array([[1.0, 3.0], [2.0, 2.0]])},
                          [{"x": 1}, {"x": 2}])
    assert out[0]["values"] == {"x": 1} and out[0]["last_chunk"]["m"]["mean"] is None
    assert out[1]["last_chunk"]["m"]["mean"] == 8.0
    assert "per_seed" not in out[1]["last_chunk"]["m"]
    assert out[0]["final"]["f"]["per_seed"] == [1.0, 3.0]
