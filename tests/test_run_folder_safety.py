"""Run folders that cannot be corrupted, and one-line errors (issue 20), through real `vbl`
processes: the folder lock, the run marker and --overwrite rules, checkpoint checksums,
bad values, the memory estimate, a full disk, refused resumes, strict metrics reading,
duplicate --sweep paths and a quiet compilation cache.

Independent processes start together (two waves) to keep the wall time low.
"""

from __future__ import annotations

import json
import re
import resource
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from tests.engine_helpers import REPO, TINY, env_for, experiments_dir, one_error_line, vbl_cmd

TIMEOUT = 300  # s per process (the test machine is shared)
RUN = ["run", "toy_bandit", *TINY, "--seeds", "4", "--quiet"]
DONE = [*RUN, "--set", "train.num_chunks=6", "--checkpoint-every", "2"]  # keeps steps 4, 6
# Enough data per leaf that the checkpoint's arrays live in their own data file.
BIG = ["run", "toy_bandit", "--set", "env.num_arms=2000", "--set", "train.pulls_per_chunk=5",
       "--set", "train.num_chunks=6", "--seeds", "64", "--checkpoint-every", "2", "--quiet"]
LONG = [*RUN, "--set", "train.num_chunks=1000000", "--checkpoint-every", "3"]

# A test experiment with a traced int, a tuple of numbers and a check() that raises
# ValueError (toy_bandit has none of these).
GUARDED = '''
from flax import struct
import jax.numpy as jnp
from vbl.engine import Experiment, Program, register
from vbl.params import param, section


@struct.dataclass
class Agent:
    window: int = param(5, doc="a traced int", ge=1)
    levels: tuple = param((0.2, 0.5), doc="a tuple of numbers")
    boom: int = param(0, doc="1 makes check() raise ValueError", static=True)

    def check(self):
        if self.boom:
            raise ValueError("boom is not allowed")


@struct.dataclass
class Config:
    agent: Agent = section(Agent, doc="the agent")


def make_program(cfg):
    return Program(init=lambda key, c: jnp.zeros(()),
                   step=lambda carry, c: (carry + c.agent.window, {"x": carry}), num_chunks=2)


register(Experiment(name="guarded_toy", description="test experiment",
                    default_config=Config(), make_program=make_program, seeds=2))
'''

BAD_VALUES = {  # name: (arguments, what the error line must say)
    "traced_int": (["run", "guarded_toy", "--set", "agent.window=99999999999"], "int32"),
    "seed": (["run", "toy_bandit", "--seed", "99999999999999999999999"], "base seed"),
    "seeds": (["run", "toy_bandit", "--seeds", "1000000000000"], "2147483647"),
    "tuple": (["run", "guarded_toy", "--set", "agent.levels=(a,b)"], "tuple of numbers"),
    "check": (["run", "guarded_toy", "--set", "agent.boom=1"], "boom is not allowed"),
    "float32": (["run", "toy_bandit", "--set", "agent.initial_value=1e39"], "float32"),
    "sweep_twice": (["run", "toy_bandit", "--sweep", "agent.epsilon=0.1,0.2", "--sweep",
                     "agent.epsilon=0.3"], "given twice"),
    # item 6: beyond any machine's memory, refused from the estimate before allocating
    "memory_seeds": (["run", "toy_bandit", "--seeds", "2000000000"], "of memory"),
    "memory_sweep": (["run", "toy_bandit", "--seeds", "1000", "--sweep", "agent.epsilon=" +
                      ",".join(f"{0.01 + i * 0.0009:.4f}" for i in range(1000)), "--sweep",
                      "agent.learning_rate=" + ",".join(f"{0.01 + i * 0.0009:.4f}"
                                                        for i in range(1000))], "of memory"),
}


def _limit_file_size(nbytes: int):
    """preexec_fn: files may not grow past ``nbytes`` (writes fail with EFBIG, as on a full
    disk; Python ignores SIGXFSZ)."""
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, resource.RLIM_INFINITY))


CPU_S = 30  #: CPU seconds an oversized run may take to be refused (about 8 s measured)


def _limit_cpu(seconds: int):
    """preexec_fn: the process is stopped (SIGXCPU) after ``seconds`` of CPU time, a bound
    that does not depend on how loaded the machine is."""
    return lambda: resource.setrlimit(resource.RLIMIT_CPU, (seconds, resource.RLIM_INFINITY))


class Procs:
    """Processes started at once, each read by a thread (which notes when it ended);
    :meth:`wait` returns ``{name: (rc, stdout, stderr)}``."""

    def __init__(self):
        self.procs: dict[str, subprocess.Popen] = {}
        self.threads: dict[str, threading.Thread] = {}
        self.results: dict[str, tuple[int, str, str]] = {}
        self.took: dict[str, float] = {}

    def start(self, name, args, env, cwd=REPO, **kw):
        t0 = time.monotonic()
        p = subprocess.Popen(vbl_cmd(*args), env=env, cwd=cwd, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)

        def read():
            o, e = p.communicate()
            self.took[name] = time.monotonic() - t0
            self.results[name] = (p.returncode, o, e)

        self.procs[name] = p
        self.threads[name] = threading.Thread(target=read, daemon=True)
        self.threads[name].start()
        return p

    def done(self, name) -> bool:
        return name in self.results

    def wait(self, names=None):
        for k in names or list(self.procs):
            self.threads[k].join(TIMEOUT)
            assert k in self.results, f"{k} did not end within {TIMEOUT} s"
        return {k: self.results[k] for k in names or list(self.procs)}

    def kill_all(self):
        for k, p in self.procs.items():
            if k not in self.results:
                p.kill()
        for t in self.threads.values():
            t.join(30)


def rows(run: Path) -> list[dict]:
    return [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]


def tree(path: Path) -> dict[str, bytes]:
    """Every file's bytes (but the lock file's, which holds the pid of the last taker)."""
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*"))
            if p.is_file() and p.name != ".vbl-lock"}


def flip_largest(state: Path) -> Path:
    """Flip one byte in the middle of the largest data file of a checkpoint's arrays."""
    f = max((p for p in state.rglob("*") if p.is_file() and p.parent.name == "d"),
            key=lambda p: p.stat().st_size)
    b = bytearray(f.read_bytes())
    b[len(b) // 2] ^= 0xFF
    f.write_bytes(bytes(b))
    return f


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("safety")
    exps = experiments_dir(tmp)
    (exps / "guarded_toy.py").write_text(GUARDED)
    env = env_for(exps)
    # the compilation cache in a fresh folder, XLA's own log level left to vbl
    cache_env = {k: v for k, v in env_for(exps, VBL_JAX_CACHE=str(tmp / "jax-cache")).items()
                 if k != "TF_CPP_MIN_LOG_LEVEL"}
    return tmp, env, cache_env


@pytest.fixture(scope="module")
def wave1(setup):
    """Every process that needs no earlier result, started together; the two concurrent
    resumes are watched while the others run."""
    tmp, env, cache_env = setup
    ps = Procs()
    foreign = tmp / "foreign"
    (foreign / "src").mkdir(parents=True)
    (foreign / "config.json").write_text("{}")
    (foreign / "src" / "important.txt").write_text("x")
    (tmp / "empty_before").mkdir()
    try:
        for k in ("race_a", "race_b"):  # item 1: two resumes into one folder at once
            ps.start(k, [*LONG, "--out", str(tmp / "race"), "--resume"], env)
        ps.start("done", [*DONE, "--out", str(tmp / "done")], env)
        ps.start("big", [*BIG, "--out", str(tmp / "big")], env)
        ps.start("cache1", [*RUN, "--out", str(tmp / "cache1")], cache_env)
        ps.start("foreign", [*RUN, "--out", str(foreign), "--overwrite"], env)
        for k, (args, _) in BAD_VALUES.items():
            cpu = {"preexec_fn": _limit_cpu(CPU_S)} if k.startswith("memory") else {}
            ps.start(k, [*args, "--quiet", "--out", str(tmp / f"bad_{k}")], env, **cpu)
        # the file-size limits are for the run folder: without the compilation cache, so
        # whether JAX's cache already holds the program (its entry is larger than these
        # limits) makes no difference
        small = dict(env, VBL_JAX_CACHE="0")
        ps.start("full_start", [*RUN, "--out", str(tmp / "full_start")], small,
                 preexec_fn=_limit_file_size(0))
        ps.start("full_start_empty", [*RUN, "--out", str(tmp / "empty_before")], small,
                 preexec_fn=_limit_file_size(0))
        ps.start("full_mid", [*DONE, "--out", str(tmp / "full_mid")], small,
                 preexec_fn=_limit_file_size(2500))
        ps.start("full_checkpoint", [*BIG, "--out", str(tmp / "full_checkpoint")], small,
                 preexec_fn=_limit_file_size(100_000))
        race = _race(ps, tmp, env)
        out = ps.wait([k for k in ps.procs if not k.startswith("race")])
    finally:
        ps.kill_all()
    out.update(race)
    return tmp, out, ps.took


def _race(ps: Procs, tmp: Path, env) -> dict:
    """The first of the two resumes to end is the refused one; while the other still runs,
    an --overwrite of its folder is refused too; then the runner is killed."""
    deadline = time.monotonic() + TIMEOUT
    while not (ps.done("race_a") or ps.done("race_b")) and time.monotonic() < deadline:
        time.sleep(0.05)
    loser, winner = ("race_a", "race_b") if ps.done("race_a") else ("race_b", "race_a")
    metrics = tmp / "race" / "metrics.jsonl"
    while ((not metrics.exists() or metrics.stat().st_size == 0) and not ps.done(winner)
           and time.monotonic() < deadline):
        time.sleep(0.05)
    ps.start("race_overwrite", [*LONG, "--out", str(tmp / "race"), "--overwrite"], env)
    out = ps.wait([loser, "race_overwrite"])
    out["race_winner_running"] = not ps.done(winner)
    ps.procs[winner].send_signal(signal.SIGKILL)
    out["race_winner"] = ps.wait([winner])[winner]
    return out


@pytest.fixture(scope="module")
def wave2(wave1, setup):
    """Processes on copies of the first wave's runs, started together (a resume with the
    right config follows the refused one)."""
    tmp, out1, _ = wave1
    _, env, cache_env = setup
    for k in ("done", "big", "cache1"):
        assert out1[k][0] == 0, (k, out1[k][2][-3000:])
    dirs = _prepare_copies(tmp)
    ps = Procs()
    try:
        ps.start("dot", [*RUN, "--out", ".", "--overwrite"], env, cwd=dirs["cwd_run"])
        ps.start("parent", [*RUN, "--out", "..", "--overwrite"], env,
                 cwd=dirs["cwd_run"] / "sub")
        ps.start("flipped", [*BIG, "--out", str(dirs["flipped"]), "--resume"], env)
        for k in ("other_config", "middle", "torn", "garbage"):
            extra = ["--set", "agent.epsilon=0.3"] if k == "other_config" else []
            ps.start(k, [*DONE, "--out", str(dirs[k]), "--resume", *extra], env)
        ps.start("cache2", [*RUN, "--out", str(tmp / "cache2")], cache_env)
        ps.start("full_mid_resume", [*DONE, "--out", str(tmp / "full_mid"), "--resume"], env)
        ps.start("empty_again", [*RUN, "--out", str(tmp / "empty_before")], env)
        ps.start("full_checkpoint_resume", [*BIG, "--out", str(tmp / "full_checkpoint"),
                                            "--resume"], env)
        ps.wait(["other_config"])
        config_after_refusal = (dirs["other_config"] / "config.json").exists()
        ps.start("same_config", [*DONE, "--out", str(dirs["other_config"]), "--resume"], env)
        out = ps.wait()
    finally:
        ps.kill_all()
    return tmp, out, dirs, config_after_refusal


def _prepare_copies(tmp: Path) -> dict[str, Path]:
    """Copies of finished runs, each damaged or changed as one test needs; the files
    before the second wave are kept in ``<name>.before``."""
    dirs = {k: tmp / k for k in ("cwd_run", "flipped", "other_config", "middle", "torn",
                                 "garbage")}
    for k, d in dirs.items():
        shutil.copytree(tmp / ("big" if k == "flipped" else "done"), d)
        if k != "cwd_run":  # as if killed after the step-4 checkpoint
            shutil.rmtree(d / "checkpoints" / "6")
    (dirs["cwd_run"] / "sub").mkdir()
    flip_largest(dirs["flipped"] / "checkpoints" / "4" / "state")
    (dirs["other_config"] / "config.json").unlink()
    lines = (dirs["middle"] / "metrics.jsonl").read_text().split("\n")
    lines[2] = lines[2][:30]  # line 3 cut short
    (dirs["middle"] / "metrics.jsonl").write_text("\n".join(lines))
    torn = dirs["torn"] / "metrics.jsonl"
    torn.write_bytes(torn.read_bytes()[:-40])
    (dirs["garbage"] / "config.json").write_text("garbage{")
    for k in ("cwd_run", "flipped", "middle", "garbage"):
        _BEFORE[k] = tree(dirs[k])
    return dirs


_BEFORE: dict[str, dict[str, bytes]] = {}


def test_two_resumes_at_once_one_refused_no_duplicate_rows(wave1):
    tmp, out, _ = wave1
    assert out["race_winner_running"], ("the running resume ended before the others",
                                        out.get("race_winner"))
    losers = [k for k in ("race_a", "race_b") if k in out]
    assert len(losers) == 1
    for k in (losers[0], "race_overwrite"):
        rc, _, err = out[k]
        assert rc != 0 and "is in use by another vbl run" in one_error_line(err), k
    steps = [r["step"] for r in rows(tmp / "race")]
    assert steps and steps == list(range(1, len(steps) + 1))  # one writer, nothing deleted


def test_overwrite_refuses_a_folder_vbl_did_not_write(wave1):
    tmp, out, _ = wave1
    rc, _, err = out["foreign"]
    assert rc != 0 and "holds no vbl run" in one_error_line(err)
    foreign = tmp / "foreign"
    assert sorted(p.name for p in foreign.rglob("*")) == ["config.json", "important.txt",
                                                            "src"]
    assert (foreign / "src" / "important.txt").read_text() == "x"


def test_overwrite_of_the_current_folder_or_a_parent_is_refused(wave2):
    _, out, dirs, _ = wave2
    for k in ("dot", "parent"):
        rc, _, err = out[k]
        assert rc != 0 and "current folder or contains it" in one_error_line(err), k
    assert tree(dirs["cwd_run"]) == _BEFORE["cwd_run"]


def test_bad_values_one_line_no_folder(wave1):
    tmp, out, _ = wave1
    for k, (_, says) in BAD_VALUES.items():
        rc, _, err = out[k]
        line = one_error_line(err)
        assert rc != 0 and says in line, (k, line)
        assert not (tmp / f"bad_{k}").exists(), k


def test_oversized_runs_refused_in_seconds(wave1):
    """A sweep of 1,000,000 points x 1000 seeds and 2e9 seeds are refused from the memory
    estimate within CPU_S seconds of CPU (the processes run under RLIMIT_CPU): nothing is
    allocated per learner and no point is validated before the estimate."""
    _, out, _ = wave1
    for k in ("memory_seeds", "memory_sweep"):
        rc, _, err = out[k]
        assert rc == 1 and "available; use fewer --seeds" in one_error_line(err), (k, rc)


def test_full_disk_at_start_leaves_nothing_behind(wave1, wave2):
    """RLIMIT_FSIZE=0 makes every write fail with EFBIG, as a full disk does (no tmpfs
    needed): the run ends in one line and leaves no file that would block the next run
    into the folder (which then succeeds)."""
    tmp, out, _ = wave1
    for k in ("full_start", "full_start_empty"):
        rc, _, err = out[k]
        assert rc != 0 and "cannot write" in one_error_line(err), k
    assert not (tmp / "full_start").exists()
    rc, _, err = wave2[1]["empty_again"]
    assert rc == 0, err[-3000:]


def test_full_disk_mid_run_then_resume(wave1, wave2):
    """Files may not grow past 2500 bytes (RLIMIT_FSIZE): metrics.jsonl fills up after a
    few chunks. The run ends in one line; --resume without the limit tolerates the torn
    last line and gives the rows of an uninterrupted run."""
    tmp, out, _ = wave1
    rc, _, err = out["full_mid"]
    assert rc != 0 and "--resume" in one_error_line(err)
    rc, _, err = wave2[1]["full_mid_resume"]
    assert rc == 0, err[-3000:]
    assert rows(tmp / "full_mid") == rows(tmp / "done")


def test_full_disk_while_a_checkpoint_is_written(wave1, wave2):
    """The checkpoint's data file (about 375 KB) may not grow past 100 KB: the checkpoint
    library's failure ends in the same one line (no log, no traceback); --resume without
    the limit then finishes the run with the rows of an uninterrupted one."""
    tmp, out, _ = wave1
    rc, _, err = out["full_checkpoint"]
    line = one_error_line(err)
    assert rc != 0 and "cannot write" in line and "--resume" in line, line
    rc, _, err = wave2[1]["full_checkpoint_resume"]
    assert rc == 0, err[-3000:]
    assert rows(tmp / "full_checkpoint") == rows(tmp / "big")


def test_flipped_byte_in_checkpoint_detected(wave2):
    _, out, dirs, _ = wave2
    rc, _, err = out["flipped"]
    line = one_error_line(err)
    assert rc != 0 and "checkpoint at step 4" in line and "checksum" in line, line
    assert "--overwrite" in line  # how to go on
    assert tree(dirs["flipped"]) == _BEFORE["flipped"]  # metrics.jsonl untouched too


def test_refused_resume_does_not_write_config_json(wave2):
    tmp, out, dirs, config_after_refusal = wave2
    rc, _, err = out["other_config"]
    assert rc != 0 and "another config" in one_error_line(err)
    assert not config_after_refusal
    rc, _, err = out["same_config"]
    assert rc == 0, err[-3000:]
    assert rows(dirs["other_config"]) == rows(tmp / "done")


def test_metrics_malformed_middle_line_refused_torn_last_line_tolerated(wave2):
    tmp, out, dirs, _ = wave2
    rc, _, err = out["middle"]
    assert rc != 0 and "line 3 is not a metrics row" in one_error_line(err)
    assert tree(dirs["middle"]) == _BEFORE["middle"]
    rc, _, err = out["torn"]
    assert rc == 0, err[-3000:]
    assert rows(dirs["torn"]) == rows(tmp / "done")


def test_garbage_config_json_on_resume_refused(wave2):
    _, out, dirs, _ = wave2
    rc, _, err = out["garbage"]
    assert rc != 0 and "config.json is unreadable" in one_error_line(err)
    assert tree(dirs["garbage"]) == _BEFORE["garbage"]


XLA_LOG_LINE = re.compile(r"^[EWF]\d{4} ", re.M)


def test_cached_run_prints_no_xla_log_lines(wave2):
    tmp, out, _, _ = wave2
    if not list((tmp / "jax-cache").rglob("*-cache")):
        pytest.skip("the toy compiled faster than the cache's threshold: nothing cached")
    rc, _, err = out["cache2"]
    assert rc == 0, err[-3000:]
    assert not XLA_LOG_LINE.search(err) and "SIGILL" not in err, err[-3000:]
