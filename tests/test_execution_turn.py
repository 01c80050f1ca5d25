"""Processes that share a ``VBL_EXECUTION_LOCK`` run their programs one at a time
(``vbl.engine.jax_setup.execution_turn``); ``vbl reproduce`` gives its workers one."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile

import pytest

from vbl.engine import reproduce
from vbl.engine.jax_setup import EXECUTION_LOCK_ENV

_HOLDER = """
import json, sys, time
from vbl.engine.jax_setup import execution_turn
spans = []
for _ in range(4):
    with execution_turn():
        t0 = time.monotonic()
        time.sleep(0.15)
        spans.append((t0, time.monotonic()))
    time.sleep(0.01)
print(json.dumps(spans))
"""


def _spans(lock: str | None) -> list[list[tuple[float, float]]]:
    """The turns (start, end) of two processes started together, per process."""
    env = dict(os.environ)
    env.pop(EXECUTION_LOCK_ENV, None)
    if lock is not None:
        env[EXECUTION_LOCK_ENV] = lock
    procs = [subprocess.Popen([sys.executable, "-c", _HOLDER], env=env, text=True,
                              stdout=subprocess.PIPE) for _ in range(2)]
    return [json.loads(p.communicate(timeout=120)[0]) for p in procs]


def _overlaps(a, b) -> int:
    return sum(1 for s0, e0 in a for s1, e1 in b if s0 < e1 and s1 < e0)


def test_processes_sharing_the_lock_never_run_at_once(tmp_path):
    a, b = _spans(str(tmp_path / "turn.lock"))
    assert len(a) == len(b) == 4
    assert _overlaps(a, b) == 0


def test_without_the_variable_nothing_waits(tmp_path):
    a, b = _spans(None)  # the same processes overlap: the test above can see a failure
    assert _overlaps(a, b) > 0


def test_workers_get_a_fresh_lock_that_is_removed_after(monkeypatch):
    monkeypatch.delenv(EXECUTION_LOCK_ENV, raising=False)
    forget = reproduce._execution_lock_for_workers()
    path = os.environ[EXECUTION_LOCK_ENV]
    assert os.path.isfile(path)
    forget()
    assert EXECUTION_LOCK_ENV not in os.environ and not os.path.exists(path)


@pytest.mark.parametrize("quick", [True, False])
def test_only_a_quick_reproduce_gives_its_workers_turns(monkeypatch, quick, tmp_path):
    """Quick runs are compile-bound: their workers take turns. Full-scale programs run
    side by side (docs/findings/compile_cost.md): their workers get no lock. A pool that
    fails to start leaves no lock behind."""
    import concurrent.futures

    seen = {}

    def no_pool(*args, **kwargs):  # the environment the workers would inherit
        seen["lock"] = os.environ.get(EXECUTION_LOCK_ENV)
        raise OSError("no processes left")

    monkeypatch.delenv(EXECUTION_LOCK_ENV, raising=False)
    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", no_pool)
    made = set(os.listdir(tempfile.gettempdir()))
    with pytest.raises(OSError, match="no processes left"):
        reproduce._run_parallel([], {}, 2, tmp_path, quick, False, False, True)
    assert (seen["lock"] is not None) == quick
    assert EXECUTION_LOCK_ENV not in os.environ
    assert not {f for f in set(os.listdir(tempfile.gettempdir())) - made
                if f.startswith("vbl-execution-")}


def test_a_lock_the_user_named_is_kept(monkeypatch, tmp_path):
    mine = str(tmp_path / "mine.lock")
    monkeypatch.setenv(EXECUTION_LOCK_ENV, mine)
    reproduce._execution_lock_for_workers()()
    assert os.environ[EXECUTION_LOCK_ENV] == mine


def test_a_run_waits_for_its_turn_then_finishes(tmp_path):
    """A `vbl run` whose lock another process holds runs no program until it is free."""
    import fcntl
    import time

    from tests.engine_helpers import TINY, env_for, experiments_dir, vbl_cmd, wait_until

    lock, out = tmp_path / "turn.lock", tmp_path / "run"
    env = env_for(experiments_dir(tmp_path), **{EXECUTION_LOCK_ENV: str(lock)})
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX)  # another process's program is running
    p = subprocess.Popen(vbl_cmd("run", "toy_bandit", *TINY, "--set", "train.num_chunks=3",
                                 "--seeds", "2", "--out", str(out), "--quiet"),
                         env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_until(lambda: (out / "config.json").exists(), "the run started", p)
        time.sleep(3.0)
        rows = out / "metrics.jsonl"
        assert p.poll() is None and (not rows.exists() or not rows.read_text().strip())
        os.close(fd)  # its turn
        _, err = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err[-2000:]
    steps = [json.loads(line)["step"] for line in rows.read_text().splitlines()]
    assert sorted(set(steps)) == [1, 2, 3]
