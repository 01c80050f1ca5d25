"""`vbl merge` takes only what the shards wrote, and `--resume` of a finished run leaves
its record alone (issue 50).

Truths: a shard's metrics.jsonl as it finished (a valid JSON edit of one value is a
changed result, and the line number is that of the edited line); the shard list of a run
in N parts (1..N); the folders that are a shard whatever path names them (a symlink, a
``..``); the summary.json a finished run wrote before its ``--resume``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.engine_helpers import TINY, one_error_line, toy_experiment

RUN = ["run", "toy_bandit", *TINY, "--seeds", "3", "--set", "train.num_chunks=2",
       "--quiet"]


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    yield from toy_experiment(tmp_path_factory.mktemp("exps"))


def vbl(*args) -> int:
    from vbl.cli import main

    return main([str(a) for a in args])


@pytest.fixture(scope="module")
def shards(toy, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("parts")
    folders = [tmp / f"s{i}of2" for i in (1, 2)]
    for i, f in enumerate(folders, 1):
        assert vbl(*RUN, "--shard", f"{i}/2", "--out", f) == 0
    return folders


def _edit_value(folder: Path, line: int) -> None:
    """Change one per-seed value of ``line`` (1-based) of metrics.jsonl, keeping it valid
    JSON (the row's own statistics are left as they were, as a hand edit would)."""
    path = folder / "metrics.jsonl"
    lines = path.read_text().splitlines()
    row = json.loads(lines[line - 1])
    metric = next(iter(row["metrics"]))
    row["metrics"][metric]["per_seed"][0] = 123.0
    lines[line - 1] = json.dumps(row)
    path.write_text("\n".join(lines) + "\n")


def test_a_hand_edited_metric_is_refused_naming_the_part_and_line(shards, tmp_path, capsys):
    edited = tmp_path / "edited"
    shutil.copytree(shards[1], edited)
    n_lines = len((edited / "metrics.jsonl").read_text().splitlines())
    assert n_lines >= 2
    _edit_value(edited, 2)
    capsys.readouterr()
    assert vbl("merge", shards[0], edited, "--out", tmp_path / "out") == 2
    err = one_error_line(capsys.readouterr().err)
    assert "shard 2/2" in err and str(edited) in err and "line 2 " in err
    assert not (tmp_path / "out").exists()
    # a removed last line is a change too
    shutil.copy(shards[1] / "metrics.jsonl", edited / "metrics.jsonl")
    text = (edited / "metrics.jsonl").read_text().splitlines(keepends=True)
    (edited / "metrics.jsonl").write_text("".join(text[:-1]))
    assert vbl("merge", shards[0], edited, "--out", tmp_path / "out") == 2
    err = one_error_line(capsys.readouterr().err)
    assert f"has {n_lines - 1} lines, the shard finished with {n_lines}" in err
    # restored byte for byte: the merge goes through
    shutil.copy(shards[1] / "metrics.jsonl", edited / "metrics.jsonl")
    assert vbl("merge", shards[0], edited, "--out", tmp_path / "out") == 0


def test_every_missing_part_is_named_the_last_too(shards, tmp_path, capsys):
    capsys.readouterr()
    for given, missing in [((0,), "shard 2/2 missing"), ((1,), "shard 1/2 missing")]:
        assert vbl("merge", *(shards[i] for i in given), "--out", tmp_path / "o") == 2
        assert missing in one_error_line(capsys.readouterr().err), given
        assert not (tmp_path / "o").exists()


def test_out_naming_a_shard_by_another_path_is_refused(shards, tmp_path, capsys):
    before = {p.name: p.read_bytes() for p in shards[0].iterdir() if p.is_file()}
    link = tmp_path / "link"
    link.symlink_to(shards[0])
    dotted = tmp_path / "nowhere" / ".." / ".." / shards[0].parent.name / shards[0].name
    capsys.readouterr()
    for out in (link, dotted, shards[0].parent / "." / shards[0].name):
        assert vbl("merge", *shards, "--out", out, "--overwrite") == 2, out
        assert "is one of the shards" in one_error_line(capsys.readouterr().err)
    assert {p.name: p.read_bytes() for p in shards[0].iterdir() if p.is_file()} == before


def test_a_taken_out_asks_for_what_merge_accepts(shards, tmp_path, capsys):
    out = tmp_path / "taken"
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    capsys.readouterr()
    assert vbl("merge", *shards, "--out", out) == 1
    err = one_error_line(capsys.readouterr().err)
    assert "exists and is not empty" in err and "--overwrite" in err
    assert "--resume" not in err
    assert (out / "mine.txt").read_text() == "keep"


def test_resume_of_a_finished_run_keeps_its_record(toy, shards, tmp_path, capsys):
    whole = tmp_path / "whole"
    assert vbl(*RUN, "--out", whole) == 0
    before = json.loads((whole / "summary.json").read_text())
    assert before["resumed_from_step"] == 0 and before["wall_time_s"] > 0
    assert vbl(*RUN, "--out", whole, "--resume") == 0
    after = json.loads((whole / "summary.json").read_text())
    assert after == before
    # a finished shard: its summary (and the checksum of its metrics) stands as written,
    # so a resume does not make an edited metrics.jsonl pass the merge
    part = tmp_path / "part"
    shutil.copytree(shards[1], part)
    written = (part / "summary.json").read_bytes()
    _edit_value(part, 1)
    assert vbl(*RUN, "--shard", "2/2", "--out", part, "--resume") == 0
    assert (part / "summary.json").read_bytes() == written
    capsys.readouterr()
    assert vbl("merge", shards[0], part, "--out", tmp_path / "out") == 2
    assert "line 1 was changed" in one_error_line(capsys.readouterr().err)


def test_a_summary_copied_from_another_part_is_refused(shards, tmp_path, capsys):
    part = tmp_path / "part"
    shutil.copytree(shards[1], part)
    shutil.copy(shards[0] / "summary.json", part / "summary.json")
    capsys.readouterr()
    assert vbl("merge", shards[0], part, "--out", tmp_path / "out") == 2
    assert f"{part}/summary.json is not shard 2/2's" in one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "out").exists()


def _reseeded(src: Path, dst: Path, lo: int) -> Path:
    """Shard 2/2 (seeds 1..2 of 3) rewritten by a faulty writer to claim seeds ``lo``..2,
    one per-seed value per seed, with the checksums of what it wrote."""
    from vbl.engine.runner import metrics_line_sums

    shutil.copytree(src, dst)
    rows = [json.loads(x) for x in (dst / "metrics.jsonl").read_text().splitlines()]
    for row in rows:
        assert row["seeds"] == [1, 3]
        row["seeds"] = [lo, 3]
        for m in row["metrics"].values():
            m["per_seed"] = ([m["per_seed"][0]] * (3 - lo) + m["per_seed"])[-(3 - lo):]
    (dst / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    summary = json.loads((dst / "summary.json").read_text())
    summary["metrics_sha256"] = metrics_line_sums(dst / "metrics.jsonl")
    (dst / "summary.json").write_text(json.dumps(summary))
    return dst


def test_a_seed_held_twice_or_by_no_part_is_refused(shards, tmp_path, capsys):
    """Seeds are split 0 | 1, 2 between the two parts; a part that claims 0..2 holds seed 0
    twice, one that claims 2 only leaves seed 1 to no part."""
    capsys.readouterr()
    twice = _reseeded(shards[1], tmp_path / "twice", 0)
    assert vbl("merge", shards[0], twice, "--out", tmp_path / "out") == 2
    assert "seed 0 of point 0 at step 1 is in two shards" in one_error_line(
        capsys.readouterr().err)
    gap = _reseeded(shards[1], tmp_path / "gap", 2)
    assert vbl("merge", shards[0], gap, "--out", tmp_path / "out") == 2
    assert "lacks step 1 (chunk 0) of point 0, seed 1" in one_error_line(
        capsys.readouterr().err)
    assert not (tmp_path / "out").exists()


def test_a_resume_after_the_last_checkpoint_equals_the_whole_run(toy, tmp_path, capsys):
    """--checkpoint-every 2 over 4 chunks checkpoints chunks 2 and 4 (docs/engine.md). A run
    that died after writing chunk 4's rows but before its checkpoint resumes from chunk 2:
    its metrics.jsonl ends as the uninterrupted run's, no row twice."""
    args = [*RUN[:-3], "--set", "train.num_chunks=4", "--checkpoint-every", "2", "--quiet"]
    whole = tmp_path / "whole"
    assert vbl(*args, "--out", whole) == 0
    assert sorted(p.name for p in (whole / "checkpoints").iterdir()
                  if p.name.isdigit()) == ["2", "4"]
    died = tmp_path / "died"
    shutil.copytree(whole, died)
    shutil.rmtree(died / "checkpoints" / "4")
    (died / "summary.json").unlink()
    assert vbl(*args, "--out", died, "--resume") == 0
    assert (died / "metrics.jsonl").read_bytes() == (whole / "metrics.jsonl").read_bytes()
    assert json.loads((died / "summary.json").read_text())["resumed_from_step"] == 2
    # a resume with other seeds is another run: refused, the folder unchanged
    before = (died / "metrics.jsonl").read_bytes()
    capsys.readouterr()
    assert vbl(*[a if a != "3" else "4" for a in args], "--out", died, "--resume") == 1
    err = one_error_line(capsys.readouterr().err)
    assert "it was run with another config" in err and "seeds" in err
    assert (died / "metrics.jsonl").read_bytes() == before
