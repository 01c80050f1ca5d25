"""Engine tests through real `vbl` processes: 4 forced CPU devices == 1 device, two
processes over 127.0.0.1 == one process, SIGKILL + --resume == uninterrupted, a corrupt
checkpoint is refused, `vbl list`."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.engine_helpers import REPO, TINY, env_for, experiments_dir, run_vbl, vbl_cmd

SWEEP = ["--sweep", "agent.learning_rate=0.1,0.5", "--seeds", "3", "--set",
         "train.num_chunks=4", "--checkpoint-every", "2"]
TIMEOUT = 300  # s per subprocess (the test machine is shared)


def rows(run: Path) -> list[dict]:
    return [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli")
    return tmp, env_for(experiments_dir(tmp))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def runs(setup):
    """Started together: one process on one device (the reference), one process on 4 forced
    CPU devices, and two processes (one device each) talking over 127.0.0.1."""
    tmp, env = setup
    port = _free_port()
    base = ["run", "toy_bandit", *TINY, *SWEEP, "--out"]
    jobs = {
        "ref": (base + [str(tmp / "ref")], env),
        "four": (base + [str(tmp / "four")],
                 dict(env, XLA_FLAGS="--xla_force_host_platform_device_count=4")),
        **{f"mp{i}": (base + [str(tmp / "mp"), "--coordinator", f"127.0.0.1:{port}",
                              "--num-processes", "2", "--process-id", str(i)], env)
           for i in range(2)}}
    procs = {k: subprocess.Popen(vbl_cmd(*a), env=e, cwd=REPO, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True) for k, (a, e) in jobs.items()}
    try:
        outs = {k: p.communicate(timeout=TIMEOUT) for k, p in procs.items()}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
    for k, p in procs.items():
        assert p.returncode == 0, f"{k}: {outs[k][1][-3000:]}"
    return tmp, {k: o[0] for k, o in outs.items()}


def test_cli_list_and_run(setup, runs):
    tmp, env = setup
    r = run_vbl(["list"], env, TIMEOUT)
    assert r.returncode == 0 and "toy_bandit" in r.stdout
    tmp, stdout = runs
    assert "agent.learning_rate=0.5" in stdout["ref"] and str(tmp / "ref") in stdout["ref"]
    assert len(rows(tmp / "ref")) == 2 * 4 + 2
    summary = json.loads((tmp / "ref" / "summary.json").read_text())
    assert summary["devices"] == 1 and summary["learners"] == 6
    assert (tmp / "ref" / "success_rate.png").stat().st_size > 1000


def test_four_devices_equal_one(runs):
    tmp, _ = runs
    assert json.loads((tmp / "four" / "summary.json").read_text())["devices"] == 4
    assert rows(tmp / "four") == rows(tmp / "ref")


def test_two_processes_equal_one(runs):
    tmp, _ = runs
    summary = json.loads((tmp / "mp" / "summary.json").read_text())
    assert summary["processes"] == 2 and summary["devices"] == 2
    assert rows(tmp / "mp") == rows(tmp / "ref")


LONG = ["--set", "train.num_chunks=150", "--seeds", "2", "--checkpoint-every", "5"]


def test_sigkill_then_resume_equals_uninterrupted(setup):
    tmp, env = setup
    out, bad = tmp / "killed", tmp / "corrupt"
    args = ["run", "toy_bandit", *TINY, *LONG, "--out", str(out)]
    started: list[subprocess.Popen] = []

    def start(cmd_args, stderr=subprocess.PIPE):
        p = subprocess.Popen(vbl_cmd(*cmd_args), env=env, cwd=REPO, stdout=subprocess.DEVNULL,
                             stderr=stderr, text=True)
        started.append(p)
        return p

    try:
        proc = start(args, stderr=subprocess.DEVNULL)
        whole = start(args[:-1] + [str(tmp / "whole")])  # uninterrupted reference, meanwhile
        metrics = out / "metrics.jsonl"
        deadline = time.monotonic() + TIMEOUT
        while time.monotonic() < deadline and proc.poll() is None:
            if metrics.exists() and len(metrics.read_text().splitlines()) >= 40:
                break
            time.sleep(0.02)
        assert proc.poll() is None, "the run ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        killed_at = len(metrics.read_text().splitlines())
        assert killed_at < 150 and any((out / "checkpoints").iterdir())

        # a corrupt checkpoint is refused with a clear message, never silently restarted
        shutil.copytree(out, bad)
        steps = sorted(int(p.name) for p in (bad / "checkpoints").iterdir() if p.name.isdigit())
        for f in (bad / "checkpoints" / str(steps[-1])).rglob("*"):
            if f.is_file():
                f.write_bytes(b"garbage")
        corrupt = start(args[:-1] + [str(bad), "--resume"])
        resumed = start(args + ["--resume"])
        errs = [p.communicate(timeout=TIMEOUT)[1] for p in (corrupt, resumed, whole)]
    finally:
        for p in started:
            if p.poll() is None:
                p.kill()
    assert corrupt.returncode == 1 and "corrupt or unreadable" in errs[0], errs[0][-2000:]
    assert resumed.returncode == 0, errs[1][-3000:]
    assert whole.returncode == 0, errs[2][-3000:]
    got, want = rows(out), rows(tmp / "whole")
    assert [x["step"] for x in got if x["chunk"] != "final"] == list(range(1, 151))
    assert got == want
    assert json.loads((out / "summary.json").read_text())["resumed_from_step"] > 0


def test_vbl_host_devices_sets_the_jax_device_count(monkeypatch):
    from vbl.engine import process
    from vbl.engine.process import use_all_cores

    monkeypatch.setattr(process, "jax_started", lambda: False)  # as before JAX starts
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.delenv("VBL_HOST_DEVICES", raising=False)
    cores = len(os.sched_getaffinity(0))
    if cores > 1:  # by default every usable core is a device
        assert use_all_cores() == cores
        assert f"--xla_force_host_platform_device_count={cores}" in os.environ["XLA_FLAGS"]
        monkeypatch.delenv("XLA_FLAGS")
    monkeypatch.setenv("VBL_HOST_DEVICES", "1")
    assert use_all_cores() == 0 and "XLA_FLAGS" not in os.environ  # one device: unchanged
    monkeypatch.setenv("VBL_HOST_DEVICES", "3")
    assert use_all_cores() == 3
    assert "--xla_force_host_platform_device_count=3" in os.environ["XLA_FLAGS"]
    # several devices wait for each other at collectives: longer than XLA's 40 s, unless
    # the user sets the wait
    assert "collective_call_terminate_timeout_seconds=3600" in os.environ["XLA_FLAGS"]
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_collective_call_terminate_timeout_seconds=5")
    assert use_all_cores() == 3
    assert "timeout_seconds=5" in os.environ["XLA_FLAGS"]
    assert "timeout_seconds=3600" not in os.environ["XLA_FLAGS"]
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=4")
    assert use_all_cores() == 0 and os.environ["XLA_FLAGS"].endswith("count=4")  # user wins
    monkeypatch.delenv("XLA_FLAGS")
    monkeypatch.setenv("VBL_HOST_DEVICES", "two")
    with pytest.raises(SystemExit) as stop:  # bad input: one line, exit 2
        use_all_cores()
    assert stop.value.code == 2
    # in a fresh process the flag really gives that many JAX devices
    env = dict(os.environ, VBL_HOST_DEVICES="2")
    env.pop("XLA_FLAGS", None)
    code = ("from vbl.engine.process import use_all_cores; use_all_cores(); import jax; "
            "print(jax.device_count())")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=TIMEOUT)
    assert out.stdout.strip() == "2", out.stderr
