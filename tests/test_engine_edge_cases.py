"""Edge cases of run folders, statistics over seeds, report cells, `vbl render`'s checks
and Monte Carlo updates past one pass: behaviour a realistic bug changed without another
test noticing (each found by ``tests/mutation_check.py``).

Truths: SciPy's Student t interval and hand-computed seed counts; a NumPy every-visit
Monte Carlo update written in closed form; the documented lock protocol of a
``vbl reproduce`` folder; the bytes of a video frame from its documented sizes.
"""

from __future__ import annotations

import fcntl
import json
import os

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats as sps

from tests.engine_helpers import one_error_line
from vbl.engine import runfolder
from vbl.engine.config import fingerprint
from vbl.engine.errors import EngineError
from vbl.engine.report import RATE, claim, headline_table, seeds_cell, stat_cell
from vbl.stats import MIN_SEEDS_BOUNDED, bounded_ci95

# ------------------------------------------------------------------ run folders


def test_a_config_json_without_its_fingerprint_is_refused():
    body = {"format": runfolder.RUN_FORMAT, "experiment": "toy_bandit", "config": {"a": 1}}
    runfolder.check_fingerprint(dict(body, fingerprint=fingerprint(body)), "run")  # intact
    for spec in (body, dict(body, fingerprint=None), dict(body, fingerprint=7)):
        with pytest.raises(EngineError, match="run/config.json has no fingerprint"):
            runfolder.check_fingerprint(spec, "run")


def test_a_top_level_field_only_one_config_json_has_is_named_as_differing(tmp_path):
    """A field added to (or missing from) a run's config.json is a difference: differing()
    names it, and the fingerprint check says what was added."""
    run = {"format": 1, "experiment": "toy", "seeds": 2, "config": {"agent.lr": 0.1}}
    edited = {**run, "base_seed": 5}
    assert runfolder.differing(edited, run) == ["base_seed"]
    assert runfolder.differing(run, edited) == ["base_seed"]
    assert runfolder.differing(run, dict(run)) == []
    spec = {**edited, "fingerprint": fingerprint(run)}
    with pytest.raises(EngineError, match="base_seed is 5, the run had null"):
        runfolder.check_fingerprint(spec, tmp_path, originals=[{**run, "fingerprint":
                                                               fingerprint(run)}])


def test_a_config_json_without_its_format_is_refused_as_format_1():
    """Folders written before formats were recorded have no "format": format 1."""
    runfolder.check_format({"format": runfolder.RUN_FORMAT}, "run")
    assert runfolder.RUN_FORMAT != 1
    for spec in ({}, {"format": 1}):
        with pytest.raises(EngineError, match=r"run is a run folder of format 1; this vbl "
                                              rf"reads format {runfolder.RUN_FORMAT} only"):
            runfolder.check_format(spec, "run")


def test_a_reproduce_folder_is_refused_to_other_writers_until_allowed(tmp_path, monkeypatch):
    """A reproduce holds OUT/.vbl-lock (pid and "reproduce" inside); a run folder inside
    OUT is refused, unless this process may write there (allow_runs_under)."""
    monkeypatch.setattr(runfolder, "_ALLOWED", set())
    out = tmp_path / "repro"
    out.mkdir()
    (out / runfolder.LOCK).write_text("4242 reproduce\n")
    fd = os.open(out / runfolder.LOCK, os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(EngineError, match=r"belongs to a vbl reproduce .*\(pid 4242\)"):
            runfolder.open_run_folder(out / "run", "toy", resume=False, overwrite=False)
        assert not (out / "run").exists()
        runfolder.allow_runs_under(out)
        runfolder.open_run_folder(out / "run", "toy", resume=False, overwrite=False).release()
        assert runfolder.is_vbl_run(out / "run")
    finally:
        os.close(fd)
    # the lock released (the reproduce ended): any process may write there
    monkeypatch.setattr(runfolder, "_ALLOWED", set())
    runfolder.open_run_folder(out / "run2", "toy", resume=False, overwrite=False).release()


# ------------------------------------------------------------------ statistics


def _t_interval(x):
    x = np.asarray(x, float)
    return sps.t.interval(0.95, x.size - 1, loc=x.mean(), scale=sps.sem(x))


@pytest.mark.parametrize("x", [[0.0, 0.0, 0.3], [1.0, 1.0, 0.7], [0.0, 0.5, 1.0]])
def test_bounded_ci95_gives_no_interval_below_min_seeds_when_either_side_crosses(x):
    lo, hi = _t_interval(x)
    assert lo < 0.0 or hi > 1.0  # the t interval crosses the range on one side or both
    assert len(x) < MIN_SEEDS_BOUNDED
    assert bounded_ci95(x, 0.0, 1.0) is None


@pytest.mark.parametrize("x", [[0.0, 0.0, 0.0, 0.4], [1.0, 1.0, 1.0, 0.6],
                               [0.0, 0.1, 0.9, 1.0]])
def test_bounded_ci95_clips_from_min_seeds_on(x):
    assert len(x) == MIN_SEEDS_BOUNDED == 4  # the documented threshold
    lo, hi = _t_interval(x)
    got = bounded_ci95(x, 0.0, 1.0)
    assert got is not None
    np.testing.assert_allclose(got, (np.mean(x), max(lo, 0.0), min(hi, 1.0)), rtol=1e-5)


def test_bounded_ci95_inside_the_range_with_three_seeds():
    x = [0.4, 0.5, 0.6]
    lo, hi = _t_interval(x)
    np.testing.assert_allclose(bounded_ci95(x, 0.0, 1.0), (0.5, lo, hi), rtol=1e-5)


def test_claim_counts_the_seeds_of_the_smaller_arm():
    rng = np.random.default_rng(0)
    a, b = rng.normal(0.5, 0.3, 3), rng.normal(0.45, 0.3, 10)
    says = claim(a, b)
    assert says.startswith("not resolved at 3 seeds"), says
    assert claim([0.6], b).startswith("not resolved (1 seed: no interval")
    assert claim(b, a[:2]).startswith("not resolved at 2 seeds")


def test_claim_of_two_equal_constant_arms_is_not_yes():
    """Equal arms have a difference of exactly 0 (interval [0, 0]): mean(a) > mean(b) is
    false, never "yes"; a constant gap above 0 is "yes"."""
    assert claim([1.0, 1.0, 1.0], [1.0, 1.0, 1.0]).startswith("not resolved at 3 seeds")
    assert claim([2.0, 2.0, 2.0], [1.0, 1.0, 1.0]).startswith("yes")


def test_stat_cell_from_a_population_std_is_the_student_t_interval():
    """stat_cell(..., n=) gets a population std (ddof 0): its interval is SciPy's Student t
    95 % half-width of the mean of the values the std came from."""
    x = np.array([0.3, 0.9, 0.4, 0.7, 0.2])
    half = sps.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size)
    cell = stat_cell({"mean": float(x.mean()), "std": float(x.std())}, fmt=".6f", n=x.size)
    assert cell == f"{x.mean():.6f} ± {half:.6f}"


def test_seeds_cell_of_a_rate_near_0_keeps_its_interval_in_the_range():
    """A success rate whose t interval crosses 0 on the low side only (4 seeds) is shown as
    SciPy's interval clipped to [0, 1], never with a negative lower end."""
    x = [0.0, 0.0, 0.0, 0.4]
    lo, hi = _t_interval(x)
    assert lo < 0.0 < hi < 1.0
    assert seeds_cell(x, fmt=".4f", bounds=RATE) == f"{0.1:.4f} [{0.0:.4f}, {hi:.4f}]"
    assert seeds_cell([1.0, 1.0, 1.0, 0.6], fmt=".4f", bounds=RATE).endswith(f"{1.0:.4f}]")


def test_paired_claim_is_students_interval_of_the_per_seed_differences():
    """Arms that vary a lot from seed to seed but move together: the paired claim is SciPy's
    paired t test's interval (resolved), the unpaired one is not."""
    b = np.array([0.1, 0.9, 0.4, 0.6, 0.2])
    a = b + np.array([0.05, 0.07, 0.06, 0.05, 0.07])
    d = a - b
    half = sps.t.ppf(0.975, d.size - 1) * sps.sem(d)
    assert claim(a, b, paired=True, fmt=".4f") == f"yes ({d.mean():+.4f} ± {half:.4f})"
    assert claim(a, b).startswith("not resolved at 5 seeds")


def _headline_result(points):
    from types import SimpleNamespace

    return SimpleNamespace(summary={"points": points, "seeds": 2}, seeds=2)


def test_headline_shows_a_metrics_final_value_before_its_last_chunks():
    point = {"values": {}, "last_chunk": {"score": {"mean": 1.0, "per_seed": [1.0, 1.0]}},
             "final": {"score": {"mean": 7.0, "per_seed": [7.0, 7.0]}}}
    table = headline_table(_headline_result([point]))
    assert "7 ± 0" in table and "1 ± 0" not in table


def test_headline_keeps_a_column_that_fills_the_width_exactly():
    """Columns are kept while the widest line stays within ``width`` characters."""
    point = {"values": {}, "final": {"score": {"mean": 0.5, "per_seed": [0.4, 0.6]}}}
    res = _headline_result([point])
    full = headline_table(res, width=1000)
    widest = max(len(line) for line in full.splitlines()[:-1])  # the note is not a column
    assert "score" in headline_table(res, width=widest)
    assert "score" not in headline_table(res, width=widest - 1)


# ------------------------------------------------------------------ vbl render's checks


def _render(*args) -> int:
    from vbl.cli import main

    return main(["render", *map(str, args)])


def test_render_refuses_too_many_episodes_before_anything_runs(tmp_path, monkeypatch, capsys):
    """Frames of 128 px height: camera 137 (512 x 480 aspect), top view 213 (320 x 192),
    panel 77 (0.6 x height) -> 427 px wide, 3 bytes a pixel; 200 frames an episode at
    most, 2 copies: 65,587,200 bytes an episode, so 1 GiB holds 16 episodes."""
    monkeypatch.setattr("vbl.engine.memory.available_memory", lambda: 1 << 30)
    out = tmp_path / "v.gif"
    capsys.readouterr()
    assert _render(tmp_path / "no-run", "--episodes", 17, "--out", out) == 2
    err = one_error_line(capsys.readouterr().err)
    assert "--episodes 17" in err and "use at most --episodes 16 " in err
    assert _render(tmp_path / "no-run", "--episodes", 16, "--out", out) == 2
    err = one_error_line(capsys.readouterr().err)
    assert "memory" not in err and "no-run" in err  # past the check: the folder is next
    assert not out.exists()


def test_render_into_a_folder_it_cannot_write_is_one_line(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    locked = False
    try:
        if os.access(ro, os.W_OK):  # root ignores the mode: make the folder immutable
            locked = os.system(f"chattr +i {ro} 2>/dev/null") == 0
            if not locked:
                pytest.skip("no way to make a folder read-only here")
        capsys.readouterr()
        assert _render(tmp_path / "no-run", "--out", ro / "v.gif") == 2
        err = one_error_line(capsys.readouterr().err)
        assert f"cannot write {ro / 'v.gif'}" in err and "pick another --out" in err
    finally:
        if locked:
            os.system(f"chattr -i {ro}")
        ro.chmod(0o755)


# ------------------------------------------------------------------ Monte Carlo past one pass


def test_mc_update_of_one_key_over_many_passes_matches_the_closed_form():
    """One (state, action) decided 700 times in one trial (3 passes of 256), another 300
    times in a second; the count c and the mean return of each key give the new value
    q + (1 - (1 - lr)**c) * (mean - q), whatever the passes."""
    from vbl.agents.monte_carlo import MC_PASS_ENTRIES, mc_init, mc_update

    length, lr, gamma = 700, 0.002, 0.99
    assert length > 2 * MC_PASS_ENTRIES
    clock = np.arange(length)
    s = np.zeros((2, length), np.int32)
    a = np.zeros((2, length), np.int32)
    s[1], a[1] = 2, 1
    n = np.array([length, 300])
    last = np.array([length - 1, 400])
    q0 = np.array([[0.3, 0.0], [0.0, 0.0], [0.0, 0.7]], np.float32)
    log = mc_init(2, length, q0.size).replace(s=jnp.asarray(s), a=jnp.asarray(a),
                                     clock=jnp.asarray(np.stack([clock, clock]), jnp.int32),
                                     n=jnp.asarray(n, jnp.int32))
    q, _, used = mc_update(jnp.asarray(q0), log, jnp.array([True, True]),
                           jnp.array([True, True]), jnp.asarray(last, jnp.int32), lr, gamma)
    want = q0.astype(np.float64)
    for (si, ai), e in (((0, 0), 0), ((2, 1), 1)):
        rets = gamma ** (last[e] - clock[:n[e]].astype(np.float64))
        want[si, ai] += (1 - (1 - lr) ** n[e]) * (rets.mean() - want[si, ai])
    np.testing.assert_allclose(np.asarray(q), want, rtol=1e-5)
    assert float(used) == length + 300


# ------------------------------------------------------------------ a full disk


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_a_full_disk_names_the_file_it_could_not_write():
    """Writing to /dev/full fails with ENOSPC on the write, not the open (as a disk that
    fills during a run): the one line still names the file."""
    from pathlib import Path

    from vbl.engine.errors import one_line
    from vbl.engine.results import MetricsLog

    with pytest.raises(OSError) as e:
        MetricsLog(Path("/dev/full")).append([{"step": 1, "metrics": {}}])
    assert one_line(e.value).startswith("cannot write /dev/full: No space left on device")


# the checkpoint library's error for a full disk: no filename, a temporary file in its text
_LIBRARY_FULL = ('OUT_OF_RANGE: Error writing "leaf_0000/0" in OCDBT database at local file '
                 '"/x/1.orbax-checkpoint-tmp/": Failed to write 7 bytes to file 11: No space '
                 "left on device [os_error_code='28']")


@pytest.mark.parametrize("raised", ["OSError", "library"])
def test_a_full_disk_while_a_checkpoint_is_saved_names_its_folder(raised, tmp_path,
                                                                  monkeypatch, capsys):
    """ENOSPC while a checkpoint is written: exit 1 with one line naming the step's folder
    (as a permission error's line names its file), no traceback."""
    import errno

    import orbax.checkpoint as ocp

    from tests.engine_helpers import TINY, experiments_dir
    from vbl.cli import main

    monkeypatch.setenv("VBL_EXPERIMENTS_DIR", str(experiments_dir(tmp_path)))

    def full(self, step, *a, **kw):
        if raised == "OSError":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        raise ValueError(_LIBRARY_FULL)

    monkeypatch.setattr(ocp.CheckpointManager, "save", full)
    out = tmp_path / "run"
    code = main(["run", "toy_bandit", "--quiet", *TINY, "--set", "train.num_chunks=2",
                 "--seeds", "2", "--checkpoint-every", "1", "--out", str(out)])
    line = one_error_line(capsys.readouterr().err)
    assert code == 1
    assert line.startswith(f"vbl: error: cannot write {out / 'checkpoints' / '1'}: No space "
                           f"left on device; free some space"), line
    assert line.endswith("continue the run with --resume"), line


def test_overwrite_deletes_nothing_outside_the_folder(tmp_path):
    """A marker edited to list ``../victim`` (or ``sub/x``): --overwrite removes only the
    folder's own top-level names."""
    run = tmp_path / "run"
    runfolder.open_run_folder(run, "toy", resume=False, overwrite=False).release()
    (tmp_path / "victim").mkdir()
    (tmp_path / "victim" / "keep.txt").write_text("keep")
    (run / "sub").mkdir()
    (run / "sub" / "x").write_text("keep")
    (run / "metrics.jsonl").write_text("{}\n")
    marker = run / runfolder.MARKER
    m = json.loads(marker.read_text())
    m["files"] += ["../victim", "sub/x", "metrics.jsonl"]
    marker.write_text(json.dumps(m))
    runfolder.open_run_folder(run, "toy", resume=False, overwrite=True).release()
    assert (tmp_path / "victim" / "keep.txt").read_text() == "keep"
    assert (run / "sub" / "x").read_text() == "keep"
    assert not (run / "metrics.jsonl").exists()


def test_files_recorded_by_their_path_are_replaced_by_overwrite(tmp_path):
    """record_files (and RunFolder.record) take a file's path as well as its name: the
    marker lists its top-level name, so --overwrite removes it."""
    run = tmp_path / "run"
    folder = runfolder.open_run_folder(run, "toy", resume=False, overwrite=False)
    for name in ("curve.png", "table.csv"):
        (run / name).write_text("x")
    runfolder.record_files(run, [run / "curve.png"])
    folder.record(run / "table.csv")
    folder.release()
    assert {"curve.png", "table.csv"} <= set(json.loads((run / runfolder.MARKER).read_text())
                                             ["files"])
    runfolder.open_run_folder(run, "toy", resume=False, overwrite=True).release()
    assert not (run / "curve.png").exists() and not (run / "table.csv").exists()


def test_resume_into_a_folder_without_a_run_is_refused(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(EngineError, match=r"cannot --resume .*mine: it holds no vbl run"):
        runfolder.open_run_folder(mine, "toy", resume=True, overwrite=False)
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


def test_overwrite_that_could_not_finish_deletes_nothing(tmp_path):
    """A listed folder that cannot be emptied (immutable, so even root may not write it):
    --overwrite is refused before any file is deleted."""
    run = tmp_path / "run"
    runfolder.open_run_folder(run, "toy", resume=False, overwrite=False).release()
    runfolder.record_files(run, ["config.json", "metrics.jsonl", "tables"])
    for name in ("config.json", "metrics.jsonl"):  # removed before "tables" if not checked
        (run / name).write_text("{}\n")
    (run / "tables" / "2").mkdir(parents=True)
    (run / "tables" / "2" / "state").write_text("x")
    stuck = run / "tables" / "2"
    if os.system(f"chattr +i {stuck} 2>/dev/null") != 0:
        pytest.skip("chattr +i is not available here")
    try:
        assert not os.access(stuck, os.W_OK)
        with pytest.raises(EngineError, match="cannot write to output folder"):
            runfolder.open_run_folder(run, "toy", resume=False, overwrite=True)
    finally:
        os.system(f"chattr -i {stuck}")
    assert (run / "config.json").exists() and (run / "metrics.jsonl").exists()
    assert (stuck / "state").read_text() == "x"


def test_a_video_write_that_fails_midway_is_one_line_and_leaves_no_file(tmp_path,
                                                                         monkeypatch):
    """A disk that fills while the frames are written: EngineError naming the file, and
    no half-written video."""
    import errno

    import imageio.v2 as imageio

    from vbl.programs.video import VideoParams, write_video

    out = tmp_path / "v.gif"

    class FullDisk:
        def __init__(self, path, **kw):
            self.path = path
            open(path, "wb").close()

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def append_data(self, img):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(imageio, "get_writer", FullDisk)
    frames = np.zeros((2, 32, 40, 3), np.uint8)
    with pytest.raises(EngineError, match=rf"cannot write {out}: No space left on device"):
        write_video(frames, ["a", "b"], out, VideoParams(height=32))
    assert not out.exists()


# ------------------------------------------------------------------ available memory


def _fake_memory(tmp_path, monkeypatch, available_kib, limit, current):
    """A /proc/meminfo with ``MemAvailable: available_kib kB`` and a cgroup folder with
    ``memory.max`` = ``limit`` (bytes or "max") and ``memory.current`` = ``current``."""
    from vbl.engine import memory

    meminfo = tmp_path / "meminfo"
    meminfo.write_text(f"MemTotal: 99999999 kB\nMemAvailable: {available_kib} kB\n")
    cgroup = tmp_path / "cgroup"
    cgroup.mkdir()
    (cgroup / "memory.max").write_text(f"{limit}\n")
    (cgroup / "memory.current").write_text(f"{current}\n")
    monkeypatch.setattr(memory, "MEMINFO", meminfo)
    monkeypatch.setattr(memory, "CGROUP_DIR", cgroup)
    return memory


def test_a_cgroup_limit_below_the_machines_memory_caps_what_is_available(tmp_path,
                                                                        monkeypatch):
    """8 GiB free on the machine, a container limit of 2 GiB of which 0.5 GiB is used:
    1.5 GiB is available, and a need of 1.6 GiB is refused while 1.4 GiB passes."""
    gib = 1 << 30
    memory = _fake_memory(tmp_path, monkeypatch, 8 * gib // 1024, 2 * gib, gib // 2)
    assert memory.available_memory() == 3 * gib // 2
    with pytest.raises(memory.MemoryError_, match="1.5 GiB is available"):
        memory.check_bytes(int(1.6 * gib), "it needs", "use less")
    assert memory.check_bytes(int(1.4 * gib), "it needs", "use less") == int(1.4 * gib)


def test_without_a_cgroup_limit_the_machines_free_memory_counts(tmp_path, monkeypatch):
    gib = 1 << 30
    memory = _fake_memory(tmp_path, monkeypatch, 3 * gib // 1024, "max", gib)
    assert memory.available_memory() == 3 * gib
    (tmp_path / "b").mkdir()
    memory = _fake_memory(tmp_path / "b", monkeypatch, gib // 1024, 4 * gib, 0)
    assert memory.available_memory() == gib  # a limit above the free memory: the free
    (memory.CGROUP_DIR / "memory.current").write_text(f"{5 * gib}\n")
    assert memory.available_memory() == 0  # over the limit: nothing left, not negative


def test_the_memory_estimate_counts_four_carries_per_learner_of_the_largest_group(
        tmp_path, monkeypatch):
    """The toy's carry: a key (2 uint32) and two float32 vectors of the arms: 8 + 8 x arms
    bytes; its traced config: 5 float32 (20 bytes); 16 bytes of keys. 3 arms: 32-byte
    carries; 5 arms: 48. Two seeds each: the 5-arm group needs 2 x (4 x 48 + 20 + 16) =
    456 bytes; exactly that much memory passes, a byte less is refused."""
    from tests.engine_helpers import toy_experiment
    from vbl.engine import memory
    from vbl.engine.sweep import make_plan

    gen = toy_experiment(tmp_path)
    toy = next(gen)
    try:
        plan = make_plan(toy, toy.default_config, {"env.num_arms": [5, 3]}, 2)
        need, details = memory.estimate(plan)
        assert need == 456 and details == {"group": 0, "learners": 2, "carry_bytes": 48}
        plan = make_plan(toy, toy.default_config, {"env.num_arms": [3, 5]}, 2)
        assert memory.estimate(plan) == (456, {"group": 1, "learners": 2, "carry_bytes": 48})
        monkeypatch.setattr(memory, "available_memory", lambda: 456)
        assert memory.check_memory(plan) == 456
        monkeypatch.setattr(memory, "available_memory", lambda: 455)
        with pytest.raises(memory.MemoryError_, match=r"about 456 B of memory \(2 learners x "
                                                      r"48 B state each x 4 copies\) but 455 B"):
            memory.check_memory(plan)
    finally:
        next(gen, None)


def test_byte_counts_are_shown_in_binary_units():
    from vbl.engine.memory import fmt_bytes

    assert [fmt_bytes(n) for n in (0, 1023, 1024, 1536, 1 << 20, 5 * (1 << 30), 1 << 60)] == [
        "0 B", "1023 B", "1.0 KiB", "1.5 KiB", "1.0 MiB", "5.0 GiB", "1024.0 PiB"]


def test_tree_bytes_counts_each_leafs_own_item_size():
    import jax

    from vbl.engine.memory import tree_bytes

    tree = {"a": np.zeros((3, 2), np.float64), "b": jax.ShapeDtypeStruct((5,), np.int8),
            "c": [np.zeros((), np.int16)]}
    assert tree_bytes(tree) == 3 * 2 * 8 + 5 + 2


def test_unknown_available_memory_refuses_nothing(monkeypatch):
    """available_memory() is 0 where the platform tells nothing: no check then."""
    from vbl.engine import memory

    monkeypatch.setattr(memory, "available_memory", lambda: 0)
    assert memory.check_bytes(1 << 50, "it needs", "use less") == 1 << 50
