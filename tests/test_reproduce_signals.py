"""`vbl reproduce` holds one lock on its output folder and stops on the first SIGINT or
SIGTERM within 5 s whatever --jobs is (issue 40, item 1), through real `vbl` processes.

Three toy paper experiments: `paper_fast` (2 chunks) and two that never end by themselves
(`paper_slow1`, `paper_slow2`: a million chunks).
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

import pytest

from tests.engine_helpers import env_for, one_error_line, vbl_cmd, wait_until, write_paper_toy

STOP_S = 5.0  #: the promise: stopped within this many seconds of the signal
TIMEOUT = 300

@pytest.fixture(scope="module")
def env(tmp_path_factory):
    d = tmp_path_factory.mktemp("paper_toys")
    for name, chunks in (("paper_fast", 2), ("paper_slow1", 1_000_000),
                         ("paper_slow2", 1_000_000)):
        write_paper_toy(d, name, chunks)
    return env_for(d)


def start(args, env) -> subprocess.Popen:
    return subprocess.Popen(vbl_cmd(*args), env=env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)


def run(args, env) -> tuple[int, str, str]:
    p = subprocess.run(vbl_cmd(*args), env=env, text=True, capture_output=True,
                       timeout=TIMEOUT)
    return p.returncode, p.stdout, p.stderr


def steps(folder: Path) -> list[int]:
    p = folder / "metrics.jsonl"
    if not p.exists():
        return []
    out = []
    for line in p.read_text().splitlines():
        try:
            out.append(json.loads(line)["step"])
        except ValueError:
            pass  # a torn last line (killed mid-write) is dropped by --resume
    return out


def stop(p: subprocess.Popen, sig: int) -> tuple[float, int, str, str]:
    t0 = time.monotonic()
    p.send_signal(sig)
    try:
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    return time.monotonic() - t0, p.returncode, out, err


def workers_alive(parent_pid: int) -> list[int]:
    """Processes whose parent is ``parent_pid`` (the reproduce's spawned workers)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == parent_pid:
                out.append(int(d.name))
    return out


@pytest.mark.parametrize("jobs,sig", [(2, signal.SIGINT), (2, signal.SIGTERM),
                                      (1, signal.SIGTERM)])
def test_first_signal_stops_reproduce_within_5_s(env, tmp_path, jobs, sig):
    """The signal goes to the parent only (as `kill PID` or a scheduler sends it); the
    workers are stopped by the parent, the finished run is kept, one line, 130 / 143;
    --resume then continues every run from where it was (no step twice)."""
    out = tmp_path / "rep"
    only = ["--only", "paper_fast", "--only", "paper_slow1"]  # --jobs 1: in this order
    p = start(["reproduce", "--quick", "--jobs", str(jobs), "--out", str(out), *only], env)
    try:
        wait_until(lambda: len(steps(out / "paper_slow1")) >= 3 and
                   (out / "paper_fast" / "summary.json").exists(), "both runs under way")
        children = workers_alive(p.pid)
        took, rc, _, err = stop(p, sig)
    finally:
        if p.poll() is None:
            p.kill()
    line = one_error_line(err)
    assert rc == (130 if sig == signal.SIGINT else 143), (rc, err)
    assert took < STOP_S, f"stopped {took:.1f} s after the signal"
    assert "--resume" in line and ("interrupted" in line or "terminated" in line), line
    time.sleep(0.5)
    assert not [c for c in children if Path(f"/proc/{c}").exists()
                and "zombie" not in Path(f"/proc/{c}/status").read_text().lower()], \
        "a worker outlived the reproduce"
    assert (out / "paper_fast" / "summary.json").exists()  # the finished run is kept
    before = steps(out / "paper_slow1")
    # --resume continues: the finished run is reported ok, the other one goes on
    rc, _, err = run(["reproduce", "--quick", "--jobs", "1", "--out", str(out), "--resume",
                      "--only", "paper_fast"], env)
    assert rc == 0, err[-3000:]
    manifest = json.loads((out / "reproduce.json").read_text())
    assert [r["status"] for r in manifest["runs"]] == ["ok"]
    p = start(["reproduce", "--quick", "--jobs", "1", "--out", str(out), "--resume",
               "--only", "paper_slow1"], env)
    try:
        wait_until(lambda: len(steps(out / "paper_slow1")) > len(before) + 2, "resumed rows")
        took, rc, _, err = stop(p, signal.SIGINT)
    finally:
        if p.poll() is None:
            p.kill()
    assert rc == 130 and took < STOP_S, (rc, took, err[-2000:])
    after = steps(out / "paper_slow1")
    assert after == list(range(1, len(after) + 1)), "a step lost or written twice"


def test_one_reproduce_per_folder_and_no_run_into_its_folders(env, tmp_path):
    """While a reproduce runs, a second one into its folder and a `vbl run` into one of its
    experiment folders are refused with one line; its own runs go on, and its report calls
    no complete run failed."""
    out = tmp_path / "rep"
    p = start(["reproduce", "--quick", "--jobs", "2", "--out", str(out), "--only",
               "paper_slow1", "--only", "paper_fast"], env)
    try:
        wait_until(lambda: len(steps(out / "paper_slow1")) >= 2, "the reproduce under way")
        for args in (["reproduce", "--quick", "--out", str(out), "--resume"],
                     ["reproduce", "--quick", "--out", str(out), "--overwrite"]):
            rc, _, err = run(args, env)
            assert rc == 1 and "in use by another vbl reproduce" in one_error_line(err), err
        rc, _, err = run(["run", "paper_fast", "--quick", "--out", str(out / "paper_fast"),
                          "--overwrite", "--quiet"], env)
        assert rc == 1 and "belongs to a vbl reproduce" in one_error_line(err), err
        assert p.poll() is None, "the reproduce stopped"
        wait_until(lambda: (out / "paper_fast" / "summary.json").exists(), "paper_fast done")
        _, rc, _, err = stop(p, signal.SIGTERM)
    finally:
        if p.poll() is None:
            p.kill()
    assert rc == 143, err
    # the folder is free again: a reproduce of the finished run reports it ok
    rc, _, err = run(["reproduce", "--quick", "--jobs", "1", "--out", str(out), "--resume",
                      "--only", "paper_fast"], env)
    assert rc == 0, err[-3000:]
    assert "| paper_fast | toy paper result paper_fast | ok |" in (out / "report.md").read_text()
