"""Run folders (vbl/engine/runfolder.py) in one process: the marker's names, what
``--overwrite`` removes and keeps, a folder written before markers, the checks before a
run starts, and what a changed ``config.json`` is said to differ in."""

from __future__ import annotations

import json
import os

import pytest

from vbl.engine import runfolder
from vbl.engine.config import fingerprint
from vbl.engine.errors import EngineError
from vbl.engine.runfolder import LOCK, MARKER, open_run_folder, record_files


def _files(path):
    return json.loads((path / MARKER).read_text())["files"]


def test_the_marker_lists_top_level_names_once_sorted(tmp_path):
    folder = open_run_folder(tmp_path / "r", "demo", resume=False, overwrite=False)
    folder.record("b.png", tmp_path / "r" / "sub" / "a.csv", "b.png")
    folder.release()
    assert _files(tmp_path / "r") == sorted([LOCK, MARKER, "a.csv", "b.png"])
    (tmp_path / "plain").mkdir()
    record_files(tmp_path / "plain", ["x"])  # no marker: not a run folder, nothing written
    assert not (tmp_path / "plain" / MARKER).exists()


def test_only_a_version_1_marker_with_a_file_list_counts(tmp_path):
    for marker, ok in (({"vbl_run": 1, "files": []}, True), ({"vbl_run": 2, "files": []}, False),
                       ({"vbl_run": 1, "files": "a"}, False), ([1], False)):
        (tmp_path / MARKER).write_text(json.dumps(marker))
        assert runfolder.is_vbl_run(tmp_path) is ok


def test_overwrite_removes_the_listed_files_their_tmp_and_links_but_nothing_else(tmp_path):
    out, keep = tmp_path / "r", tmp_path / "target"
    keep.mkdir()
    (keep / "data").write_text("x")
    f = open_run_folder(out, "demo", resume=False, overwrite=False)
    (out / "plots").mkdir()
    (out / "plots" / "a.png").write_text("x")
    (out / "summary.json").write_text("{}")
    (out / "summary.json.tmp").write_text("{")
    os.symlink(keep, out / "link")
    f.record("plots", "summary.json", "link")
    f.release()
    (out / "notes.txt").write_text("the user's")
    open_run_folder(out, "demo", resume=False, overwrite=True).release()
    assert sorted(p.name for p in out.iterdir()) == sorted([LOCK, MARKER, "notes.txt"])
    assert (keep / "data").read_text() == "x"  # a link is removed, never its target
    assert _files(out) == sorted([LOCK, MARKER])


def test_a_folder_written_before_markers_resumes_and_lists_the_engines_files(tmp_path):
    out = tmp_path / "old"
    out.mkdir()
    for name in ("config.json", "metrics.jsonl"):
        (out / name).write_text("{}")
    (out / "mine.txt").write_text("x")
    open_run_folder(out, "demo", resume=True, overwrite=False).release()
    assert _files(out) == sorted([LOCK, MARKER, "config.json", "metrics.jsonl"])


def test_the_checks_before_a_run_starts(tmp_path):
    check = runfolder.check_new_folder
    with pytest.raises(EngineError, match="exclude each other"):
        check(tmp_path / "new", resume=True, overwrite=True)
    (tmp_path / "file").write_text("x")
    with pytest.raises(EngineError, match="not a folder"):
        check(tmp_path / "file", resume=False, overwrite=False)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(EngineError, match="use --resume to continue it, --overwrite"):
        check(tmp_path / "full", resume=False, overwrite=False)
    with pytest.raises(EngineError, match="not empty; use --overwrite"):
        check(tmp_path / "full", resume=False, overwrite=False, resumable=False)
    (tmp_path / "empty").mkdir()
    check(tmp_path / "empty", resume=False, overwrite=False)


def test_a_config_json_without_format_is_format_1():
    runfolder.check_format({"format": runfolder.RUN_FORMAT}, "run")
    with pytest.raises(EngineError, match="run is a run folder of format 1;"):
        runfolder.check_format({}, "run")


@pytest.mark.parametrize("text, want", [("123 reproduce\n", ("123", "reproduce")),
                                        ("123\n", ("123", "run")), ("", ("?", "run"))])
def test_a_lock_names_its_holder(tmp_path, text, want):
    (tmp_path / LOCK).write_text(text)
    assert runfolder._holder(tmp_path / LOCK) == want


def test_a_changed_config_names_the_top_level_fields_first_then_the_parameters():
    run = {"format": 2, "experiment": "x", "seeds": 4, "base_seed": 0,
           "config": {"a.b": 1, "a.c": 2, "z": 3, "y": 4, "w": "s" * 80}}
    edited = {**run, "seeds": 5, "base_seed": 1,
              "config": {"a.b": 9, "a.c": 8, "z": 7, "y": 6, "w": "t" * 80}}
    assert runfolder.differing(edited, run) == ["seeds", "base_seed", "a.b", "a.c", "w", "y",
                                                "z"]
    spec = {**edited, "fingerprint": fingerprint(run)}
    with pytest.raises(EngineError) as e:
        runfolder.check_fingerprint(spec, "r", [run])
    msg = str(e.value)
    assert "seeds is 5, the run had 4, base_seed is 1, the run had 0, a.b is 9" in msg
    assert "a.c is 8, the run had 2, ...;" in msg and "y is" not in msg
    one = {**run, "config": {**run["config"], "w": "t" * 80}}
    with pytest.raises(EngineError) as e:
        runfolder.check_fingerprint({**one, "fingerprint": fingerprint(run)}, "r", [run])
    assert f'w is "{"t" * 56}..., the run had "{"s" * 56}...;' in str(e.value)
