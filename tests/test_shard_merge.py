"""Independent shards (`vbl run EXP --shard I/N`) and `vbl merge` (issue 39, item 3), and
`--coordinator auto` (item 4).

The reference is the unsharded run of the toy bandit. Merging its 2 or 3 shards must give
the same bytes in metrics.jsonl, config.json and report.md, and the same summary but for
the entries that say how the shards ran. The toy's per-learner arithmetic does not depend
on the number of learners in a compiled call as long as it holds more than one (tested
in tests/test_engine_cli.py for device counts), so the shards here hold at least two
learners of each group they run.
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
from pathlib import Path

import pytest

from tests.engine_helpers import (
    REPO,
    TINY,
    env_for,
    experiments_dir,
    one_error_line,
    toy_experiment,
    vbl_cmd,
)

RUN = ["run", "toy_bandit", *TINY, "--sweep", "agent.learning_rate=0.1,0.5", "--seeds", "3",
       "--set", "train.num_chunks=4", "--checkpoint-every", "2", "--quiet"]
# env.num_arms is static: two groups (one compilation each); 2 seeds x 2 points
STATIC = ["run", "toy_bandit", "--set", "train.pulls_per_chunk=5", "--sweep",
          "env.num_arms=3,4", "--seeds", "2", "--set", "train.num_chunks=3", "--quiet"]
HOW = ("wall_time_s", "resumed_from_step", "devices", "processes", "shards")
TIMEOUT = 300


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    yield from toy_experiment(tmp_path_factory.mktemp("exps"))


def vbl(*args) -> int:
    from vbl.cli import main

    return main([str(a) for a in args])


def run_shards(base: list, tmp: Path, name: str, n: int) -> list[Path]:
    folders = [tmp / f"{name}-{i}of{n}" for i in range(1, n + 1)]
    for i, f in enumerate(folders, 1):
        assert vbl(*base, "--shard", f"{i}/{n}", "--out", f) == 0
    return folders


@pytest.fixture(scope="module")
def runs(toy, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("shards")
    assert vbl(*RUN, "--out", tmp / "whole") == 0
    return tmp, {n: run_shards(RUN, tmp, "s", n) for n in (2, 3)}


def rows(folder: Path) -> list[dict]:
    return [json.loads(x) for x in (folder / "metrics.jsonl").read_text().splitlines()]


def same_run(merged: Path, whole: Path) -> None:
    for name in ("metrics.jsonl", "config.json", "report.md"):
        assert (merged / name).read_bytes() == (whole / name).read_bytes(), name
    got, want = (json.loads((f / "summary.json").read_text()) for f in (merged, whole))
    assert {k: v for k, v in got.items() if k not in HOW} == \
        {k: v for k, v in want.items() if k not in HOW}
    assert {p.name for p in merged.glob("*.png")} == {p.name for p in whole.glob("*.png")}


@pytest.mark.parametrize("n", [2, 3])
def test_merged_shards_equal_the_whole_run(runs, n):
    tmp, shards = runs
    out = tmp / f"merged{n}"
    assert vbl("merge", *reversed(shards[n]), "--out", out) == 0  # any order
    same_run(out, tmp / "whole")
    assert sorted((out / "metrics.jsonl").read_text().splitlines()) == \
        sorted((tmp / "whole" / "metrics.jsonl").read_text().splitlines())
    summary = json.loads((out / "summary.json").read_text())
    assert [s["shard"] for s in summary["shards"]] == [f"{i}/{n}" for i in range(1, n + 1)]
    assert summary["learners"] == 6 and sum(s["learners"] for s in summary["shards"]) == 6
    # the run used every shard's devices and processes: the sums of the shards' own records
    each = [json.loads((f / "summary.json").read_text()) for f in shards[n]]
    assert [summary[k] for k in ("devices", "processes")] == \
        [sum(e[k] for e in each) for k in ("devices", "processes")] and summary["devices"] >= n


def test_report_of_one_shard_asks_for_the_merge(runs, capsys):
    tmp, shards = runs
    capsys.readouterr()
    assert vbl("report", shards[2][0]) == 2  # like any folder that is not a finished run
    assert "part 1/2 of a sharded run: merge its parts first" in one_error_line(
        capsys.readouterr().err)


def test_each_shard_holds_its_seeds_of_the_whole_run(runs):
    """Learner = point x seeds + seed; shard i of N holds learners [(i-1)L/N, iL/N)."""
    tmp, shards = runs
    whole = {(r["step"], r["chunk"], r["point"]): r for r in rows(tmp / "whole")}
    for n, folders in shards.items():
        held = []
        for i, folder in enumerate(folders, 1):
            spec = json.loads((folder / "config.json").read_text())
            assert spec["shard"]["index"] == i and spec["shard"]["count"] == n
            for r in rows(folder):
                lo, hi = r["seeds"]
                ref = whole[(r["step"], r["chunk"], r["point"])]
                for k, st in r["metrics"].items():
                    assert st["per_seed"] == ref["metrics"][k]["per_seed"][lo:hi]
                if r["chunk"] == 0:
                    held += [r["point"] * 3 + s for s in range(lo, hi)]
            assert held[-1] + 1 == i * 6 // n  # contiguous parts, in order
        assert held == list(range(6))


def test_a_shard_may_hold_no_learner_of_a_group(toy, tmp_path):
    assert vbl(*STATIC, "--out", tmp_path / "whole") == 0
    shards = run_shards(STATIC, tmp_path, "s", 2)
    assert {r["group"] for r in rows(shards[0])} == {0}
    assert {r["group"] for r in rows(shards[1])} == {1}
    assert vbl("merge", *shards, "--out", tmp_path / "merged") == 0
    same_run(tmp_path / "merged", tmp_path / "whole")


def test_a_failed_shard_reruns_alone_with_resume(runs, tmp_path, capsys):
    tmp, shards = runs
    parts = [tmp_path / p.name for p in shards[3]]
    for src, dst in zip(shards[3], parts, strict=True):
        shutil.copytree(src, dst)
    # shard 2 "died" in chunk 4: no summary, its last checkpoint (step 4) lost, a torn row
    broken = parts[1]
    (broken / "summary.json").unlink()
    shutil.rmtree(broken / "checkpoints" / "4")
    kept = [x for x in (broken / "metrics.jsonl").read_text().splitlines()
            if json.loads(x)["step"] <= 3]
    (broken / "metrics.jsonl").write_text("\n".join(kept) + "\n" + kept[-1][:30])
    capsys.readouterr()
    assert vbl("merge", *parts, "--out", tmp_path / "m") == 2
    err = one_error_line(capsys.readouterr().err)
    assert "shard 2/3" in err and "has not finished" in err and "--resume" in err
    assert not (tmp_path / "m").exists()
    assert vbl(*RUN, "--shard", "2/3", "--out", broken, "--resume") == 0
    assert json.loads((broken / "summary.json").read_text())["resumed_from_step"] == 2
    assert vbl("merge", *parts, "--out", tmp_path / "m") == 0
    same_run(tmp_path / "m", tmp / "whole")
    # the merged summary says how the parts ran: the latest step one resumed from, the
    # sum of their wall times, each part's own record
    merged = json.loads((tmp_path / "m" / "summary.json").read_text())
    each = [json.loads((p / "summary.json").read_text()) for p in parts]
    assert [s["resumed_from_step"] for s in merged["shards"]] == [0, 2, 0]
    assert merged["resumed_from_step"] == 2
    assert merged["wall_time_s"] == pytest.approx(sum(s["wall_time_s"] for s in each))


def test_resume_as_another_shard_is_refused(runs, tmp_path, capsys):
    tmp, shards = runs
    folder = tmp_path / "s"
    shutil.copytree(shards[2][0], folder)
    capsys.readouterr()
    assert vbl(*RUN, "--shard", "2/2", "--out", folder, "--resume") == 1
    err = one_error_line(capsys.readouterr().err)
    assert "its shard: part 1/2" in err and "this run part 2/2" in err


def _edited(src: Path, dst: Path, **changes) -> Path:
    shutil.copytree(src, dst)
    spec = json.loads((dst / "config.json").read_text())
    spec.update(changes)
    (dst / "config.json").write_text(json.dumps(spec, indent=1) + "\n")
    return dst


def test_bad_shard_sets_are_one_line_exit_2(runs, toy, tmp_path, capsys, monkeypatch):
    tmp, shards = runs
    two, three = shards[2], shards[3]
    cases = [
        ([three[0], three[2]], "shard 2/3 missing"),
        ([two[0], two[0], two[1]], "shard 1/2 is given twice"),
        ([two[0], three[1]], "the shards of one run share N"),
        ([two[0], tmp / "whole"], "is a whole run, not a shard"),
        ([two[0], tmp_path / "nothing"], "is not a run folder"),
        ([two[0], _edited(two[1], tmp_path / "fmt", format=1)], "of format 1"),
        ([two[0], _edited(two[1], tmp_path / "seeds", seeds=4)], "was changed after the run"),
    ]
    # the same part of a run with another base seed, and one from another commit
    assert vbl(*RUN, "--seed", "1", "--shard", "2/2", "--out", tmp_path / "seed1") == 0
    cases.append(([two[0], tmp_path / "seed1"], "shards of different runs (they differ in "
                                                "base_seed)"))
    monkeypatch.setattr("vbl.engine.machine.git_commit", lambda: "0123abc")
    assert vbl(*RUN, "--shard", "2/2", "--out", tmp_path / "commit") == 0
    cases.append(([two[0], tmp_path / "commit"], "from commit 0123abc"))
    capsys.readouterr()
    for folders, what in cases:
        assert vbl("merge", *folders, "--out", tmp_path / "out") == 2, what
        assert what in one_error_line(capsys.readouterr().err)
        assert not (tmp_path / "out").exists()


def test_merge_never_overwrites(runs, tmp_path, capsys):
    tmp, shards = runs
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    capsys.readouterr()
    assert vbl("merge", *shards[2], "--out", out) == 1
    assert "exists and is not empty" in one_error_line(capsys.readouterr().err)
    assert vbl("merge", *shards[2], "--out", out, "--overwrite") == 1
    assert "holds no vbl run" in one_error_line(capsys.readouterr().err)
    assert (out / "mine.txt").read_text() == "keep"
    # into one of the shards, even with --overwrite: refused before anything is touched
    before = (shards[2][0] / "metrics.jsonl").read_bytes()
    assert vbl("merge", *shards[2], "--out", shards[2][0], "--overwrite") == 2
    assert "is one of the shards" in one_error_line(capsys.readouterr().err)
    assert (shards[2][0] / "metrics.jsonl").read_bytes() == before
    # a merged folder is vbl's: --overwrite replaces it
    assert vbl("merge", *shards[2], "--out", tmp_path / "m") == 0
    assert vbl("merge", *shards[3], "--out", tmp_path / "m", "--overwrite") == 0
    same_run(tmp_path / "m", tmp / "whole")


def test_bad_shard_option_is_one_line_exit_2(toy, tmp_path, capsys):
    capsys.readouterr()
    for text, what in [("0/3", "must be in 1..N"), ("4/3", "must be in 1..N"),
                       ("x", "takes I/N"), ("1/2/3", "takes I/N"),
                       ("1/7", "at most 6 parts")]:
        assert vbl(*RUN, "--shard", text, "--out", tmp_path / "x") == 2, text
        assert what in one_error_line(capsys.readouterr().err), text
        assert not (tmp_path / "x").exists()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_coordinator_auto_detects_slurm(runs, tmp_path):
    """Two processes started as SLURM starts a job's tasks (the variables srun sets) find
    each other with --coordinator auto, and give the one-process run's metrics."""
    tmp, _ = runs
    env = env_for(experiments_dir(tmp_path))
    for k in list(env):
        if k.startswith(("SLURM_", "OMPI_", "JAX_COORDINATOR")):
            env.pop(k)
    bare = subprocess.run(vbl_cmd(*RUN, "--coordinator", "auto", "--out", tmp_path / "x"),
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT)
    assert bare.returncode == 2
    assert "detected no cluster environment" in one_error_line(bare.stderr)
    slurm = dict(env, SLURM_JOB_ID="1", SLURM_STEP_NODELIST="localhost", SLURM_NTASKS="2",
                 JAX_COORDINATOR_PORT=str(_free_port()))
    procs = [subprocess.Popen(vbl_cmd(*RUN, "--coordinator", "auto", "--out", tmp_path / "mp"),
                              env=dict(slurm, SLURM_PROCID=str(i), SLURM_LOCALID=str(i)),
                              cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True) for i in range(2)]
    try:
        errs = [p.communicate(timeout=TIMEOUT)[1] for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    assert [p.returncode for p in procs] == [0, 0], errs
    assert json.loads((tmp_path / "mp" / "summary.json").read_text())["processes"] == 2
    assert rows(tmp_path / "mp") == rows(tmp / "whole")


def test_shards_partition_the_learners():
    """For every L and N <= L: the parts cover 0..L-1 once, in order, sizes differing by at
    most one; within a group, the members are the group's learners in the part."""
    from vbl.engine.sweep import Shard, _members

    for total in range(1, 40):
        for n in range(1, total + 1):
            ranges = [Shard(i, n).learner_range(total) for i in range(1, n + 1)]
            assert [x for lo, hi in ranges for x in range(lo, hi)] == list(range(total))
            sizes = {hi - lo for lo, hi in ranges}
            assert max(sizes) - min(sizes) <= 1 and min(sizes) >= 1
    seeds, ids = 3, [0, 2, 3]  # a group of points 0, 2, 3 (point 1 is another group's)
    got = _members(ids, seeds, 4, 10)  # learners 4..9: point 1 seeds 1-2, 2 all, 3 seed 0
    assert got == [(2, 0, 3), (3, 0, 1)]
    assert _members(ids, seeds, 3, 6) == []
