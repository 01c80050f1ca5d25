"""What ``vbl reproduce`` plans before anything runs (vbl/engine/reproduce.py): its jobs
and folders, its worker count, the committed times it orders chains by, and the times a
resume keeps."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

from vbl.engine import reproduce as rp
from vbl.engine.reproduce import Job


def _exp(presets=(), group=None, in_quick=True):
    return SimpleNamespace(published_presets=presets, group=group, in_quick_reproduce=in_quick)


def test_jobs_are_each_default_then_its_presets_and_quick_runs_defaults_only():
    exps = {"a": _exp(("p", "q")), "b": _exp()}
    assert rp.reproduce_jobs(exps) == [Job("a"), Job("a", "p"), Job("a", "q"), Job("b")]
    assert rp.reproduce_jobs(exps, quick=True) == [Job("a"), Job("b")]
    assert [j.folder for j in rp.reproduce_jobs(exps)] == ["a", "a-p", "a-q", "b"]


def test_a_full_run_only_result_leaves_the_quick_jobs_alone():
    """in_quick_reproduce=False drops the default and presets under --quick only."""
    exps = {"a": _exp(("p",)), "c": _exp(("r",), in_quick=False), "b": _exp()}
    assert rp.reproduce_jobs(exps) == [Job("a"), Job("a", "p"), Job("c"), Job("c", "r"),
                                       Job("b")]
    assert rp.reproduce_jobs(exps, quick=True) == [Job("a"), Job("b")]


def test_quick_only_of_a_full_run_only_result_is_refused_before_any_folder(tmp_path):
    """`vbl reproduce --quick --only NAME` of a full-run-only result names it and what to
    run instead, and writes nothing (an empty quick report would say nothing)."""
    import pytest

    from vbl.params import ParamError

    with pytest.raises(ParamError, match=r"ppo_comparator runs in the full reproduce only.*"
                       r"drop --quick, or run `vbl run ppo_comparator --quick`"):
        rp.reproduce(tmp_path / "out", quick=True, quiet=True,
                     names=["table1_identification", "ppo_comparator"])
    assert not (tmp_path / "out").exists()


def test_one_worker_per_core_at_most_one_per_run(monkeypatch):
    monkeypatch.setattr(rp.os, "cpu_count", lambda: 4)
    assert [rp.default_jobs(n) for n in (0, 1, 3, 9)] == [1, 1, 3, 4]
    monkeypatch.setattr(rp.os, "cpu_count", lambda: None)
    assert rp.default_jobs(5) == 1


def test_committed_seconds_of_the_runs_that_have_them(tmp_path):
    (tmp_path / "reproduce-quick").mkdir()
    (tmp_path / "reproduce-quick" / rp.REPRODUCE_MANIFEST).write_text(json.dumps(
        {"runs": [{"folder": "a", "seconds": 3}, {"folder": "b"}]}))
    assert rp.committed_seconds(True, tmp_path) == {"a": 3.0}
    assert rp.committed_seconds(False, tmp_path) == {}


def test_chains_group_their_experiments_longest_first():
    exps = {"a": _exp(group="g"), "b": _exp(group="g"), "c": _exp(), "d": _exp()}
    jobs = [Job("a"), Job("c"), Job("b"), Job("d")]
    chains = rp._chains(jobs, exps, {"a": 1.0, "b": 2.0, "c": 5.0, "d": 9.0})
    assert chains == [[Job("d")], [Job("c")], [Job("a"), Job("b")]]
    # a run without a time counts the mean of the others (here 4.0): after "c" (5.0)
    chains = rp._chains(jobs, exps, {"a": 1.0, "b": 2.0, "c": 5.0, "x": 8.0})
    assert chains == [[Job("c")], [Job("d")], [Job("a"), Job("b")]]


def test_a_resume_keeps_the_times_of_the_runs_that_finished(tmp_path):
    runs = [{"folder": "a", "status": "ok", "seconds": 3, "cpu_s": 5.5, "peak_rss_mb": 10},
            {"folder": "b", "status": "ok", "seconds": 4, "peak_rss_mb": 11},
            {"folder": "c", "status": "failed", "seconds": 5, "peak_rss_mb": 12}]
    (tmp_path / rp.REPRODUCE_MANIFEST).write_text(json.dumps({"runs": runs}))
    for name in ("a", "c"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text("{}")
    todo = [Job("a"), Job("b"), Job("c")]
    assert rp._finished_times(tmp_path, todo) == {
        "a": {"seconds": 3.0, "cpu_s": 5.5, "peak_rss_mb": 10.0}}
    assert rp._finished_times(tmp_path / "none", todo) == {}
    del runs[0]["cpu_s"]  # a manifest written before CPU time was recorded: null, not 0
    (tmp_path / rp.REPRODUCE_MANIFEST).write_text(json.dumps({"runs": runs}))
    kept = rp._finished_times(tmp_path, todo)["a"]
    assert kept["seconds"] == 3.0 and math.isnan(kept["cpu_s"])
