"""Real `vbl` processes, one after the other: SIGTERM like SIGINT (the stop line's own
command resumes the run), a hand-edited config.json, --overwrite into a folder it cannot
write, broken pipes, ASCII output, sys.exit at a script's import, duplicate sweep values,
bad VBL_HOST_DEVICES, an empty HOME, URL-encoded report links, and two guards (the memory
estimate in bytes, the float32 bounds check on the rounded value). `vbl reproduce`'s
signals: tests/test_reproduce_signals.py."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from tests.engine_helpers import (
    REPO,
    TINY,
    TOY,
    env_for,
    experiments_dir,
    one_error_line,
    vbl_cmd,
    wait_until,
)

TIMEOUT = 300
RUN = ["run", "toy_bandit", *TINY, "--seeds", "4", "--quiet"]
DONE = [*RUN, "--set", "train.num_chunks=6", "--checkpoint-every", "2"]
LONG = [*RUN, "--set", "train.num_chunks=1000000", "--checkpoint-every", "3"]

# A test experiment with an `lt` bound and paper rows (toy_bandit has neither).
BOUNDED = '''
from vbl.engine.registry import load_script
toy = load_script({toy!r})  # once, in sys.modules, as the engine loads scripts
from flax import struct
import jax.numpy as jnp
from vbl.engine import Experiment, Program, register
from vbl.engine.experiment import PaperRow
from vbl.params import param, section


@struct.dataclass
class Agent:
    share: float = param(0.5, doc="a fraction below 1", gt=0.0, lt=1.0)


@struct.dataclass
class Config:
    agent: Agent = section(Agent, doc="the agent")


def make_program(cfg):
    return Program(init=lambda key, c: jnp.zeros(()),
                   step=lambda carry, c: (carry + c.agent.share, {{"x": carry}}),
                   num_chunks=2)


register(Experiment(name="bounded_toy", description="test experiment",
                    default_config=Config(), make_program=make_program, seeds=2,
                    paper_result=True, paper_rows=lambda r: [PaperRow("x", "1", "2")]))
'''

EXITS = "import sys\nsys.exit(0)\n"


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("part2")
    exps = experiments_dir(tmp)
    (exps / "bounded_toy.py").write_text(BOUNDED.format(toy=str(TOY)))
    return tmp, env_for(exps)


def run(args, env, cwd=REPO, timeout=TIMEOUT) -> tuple[int, str, str]:
    p = subprocess.run(vbl_cmd(*args), env=env, cwd=cwd, text=True, capture_output=True,
                       timeout=timeout)
    return p.returncode, p.stdout, p.stderr


def rows(run_dir: Path) -> list[int]:
    return [json.loads(x)["step"] for x in (run_dir / "metrics.jsonl").read_text().splitlines()]


def tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*"))
            if p.is_file() and p.name != ".vbl-lock"}


@pytest.fixture(scope="module")
def done(setup):
    tmp, env = setup
    rc, _, err = run([*DONE, "--out", str(tmp / "done")], env)
    assert rc == 0, err[-3000:]
    return tmp / "done"


def copy(done: Path, name: str) -> Path:
    d = done.parent / name
    shutil.copytree(done, d)
    return d


# ------------------------------------------------------------------ SIGTERM


def checkpoint_steps(out: Path) -> int:
    """The latest checkpointed step of a run folder (0 before the first); older steps are
    deleted as new ones arrive, so a test waits for "at least", never for one step."""
    return max((int(d.name) for d in (out / "checkpoints").glob("*") if d.name.isdigit()),
               default=0)


def stop(p: subprocess.Popen, sig: int) -> tuple[float, str]:
    """Send ``sig`` to ``p``; (seconds until it exited, its stderr)."""
    t0 = time.monotonic()
    p.send_signal(sig)
    _, err = p.communicate(timeout=60)
    return time.monotonic() - t0, err


def test_sigterm_stops_a_run_like_sigint_and_resume_finishes_it(setup):
    tmp, env = setup
    out = tmp / "term"
    p = subprocess.Popen(vbl_cmd(*LONG, "--out", str(out)), env=env, cwd=REPO, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_until(lambda: checkpoint_steps(out) >= 6, "checkpoint step 6", p)
        took, err = stop(p, signal.SIGTERM)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 143 and took < 5.0, (p.returncode, took)
    line = one_error_line(err)
    assert "terminated" in line and f"the checkpoint of chunk {checkpoint_steps(out)} is kept" \
        in line, line
    assert not list(out.rglob("*.tmp")), "a temporary file was left behind"
    steps = rows(out)
    assert steps == list(range(1, len(steps) + 1))
    # the checkpoint state is consistent: the line's own command continues from it, no step
    # twice
    command = shlex.split(line.split("continue with: ", 1)[1])
    assert command[:3] == ["vbl", "run", "toy_bandit"] and command[-3:] == [
        "--out", str(out), "--resume"], command
    p = subprocess.Popen(vbl_cmd(*command[1:], "--quiet"), env=env, cwd=REPO, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_until(lambda: len(rows(out)) >= len(steps) + 3, "3 resumed rows", p)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130 and "interrupted" in one_error_line(err)
    again = rows(out)
    assert again == list(range(1, len(again) + 1))


def test_sigterm_stops_vbl_bench_and_leaves_nothing_behind(setup):
    tmp, env = setup
    bench = tmp / "bench_src" / "benchmarks"
    bench.mkdir(parents=True)
    (bench / "results").mkdir()
    (bench / "slow.py").write_text("import time\nif __name__ == \"__main__\":\n"
                                   "    print('started', flush=True)\n    time.sleep(600)\n")
    before = sorted(p.relative_to(bench.parent) for p in bench.parent.rglob("*"))
    out = tmp / "bench_out"
    p = subprocess.Popen(vbl_cmd("bench", "--out", str(out), "slow"), cwd=REPO, text=True,
                         env=dict(env, VBL_BENCH_DIR=str(bench)),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert p.stdout.readline().startswith("== slow")
        assert p.stdout.readline().startswith("started")
        took, err = stop(p, signal.SIGTERM)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 143 and took < 5.0, (p.returncode, took, err)
    assert "terminated" in one_error_line(err)
    assert not (out / ".scripts").exists() and list(out.iterdir()) == []
    assert sorted(p.relative_to(bench.parent) for p in bench.parent.rglob("*")) == before


# ------------------------------------------------------------------ config.json


def test_hand_edited_config_json_is_refused_by_report_and_resume(setup, done):
    tmp, env = setup
    edited = {}
    for name, key, value in (("lr", ("config", "agent.learning_rate"), 0.5),
                             ("seeds", ("seeds",), 8)):
        d = copy(done, f"edited_{name}")
        spec = json.loads((d / "config.json").read_text())
        if len(key) == 2:
            spec[key[0]][key[1]] = value
        else:
            spec[key[0]] = value
        (d / "config.json").write_text(json.dumps(spec, indent=1) + "\n")
        edited[name] = d
    for name, says in (("lr", "agent.learning_rate is 0.5, the run had 0.1"),
                       ("seeds", "seeds is 8, the run had 4")):
        rc, out, err = run(["report", str(edited[name])], env)
        line = one_error_line(err)
        assert rc == 2 and "changed after the run" in line and says in line, line
        assert out == ""
    # --resume with the original options names exactly what the file changed
    before = tree(edited["lr"])
    rc, _, err = run([*DONE, "--out", str(edited["lr"]), "--resume"], env)
    line = one_error_line(err)
    assert rc == 1 and "agent.learning_rate is 0.5, the run had 0.1" in line, line
    # ... and with the edited value asked for, too (never an empty list)
    rc, _, err = run([*DONE, "--out", str(edited["lr"]), "--resume", "--set",
                      "agent.learning_rate=0.5"], env)
    line = one_error_line(err)
    assert rc == 1 and "agent.learning_rate" in line and "[]" not in line, line
    assert tree(edited["lr"]) == before
    # a real config difference names its parameters, also the top-level ones
    rc, _, err = run([*DONE, "--out", str(copy(done, "other")), "--resume", "--seed", "3",
                      "--set", "agent.epsilon=0.3"], env)
    line = one_error_line(err)
    assert rc == 1 and "differs in ['base_seed', 'agent.epsilon']" in line, line


# ------------------------------------------------------------------ --overwrite


@pytest.fixture
def immutable(done):
    """A finished run in a folder no file can be created in or removed from, even by root
    (``chattr +i``); its lock file and its ``checkpoints/`` stay writable, as in the
    issue's probe."""
    d = Path(tempfile.mkdtemp(prefix="vbl-immutable-"))
    run_dir = d / "run"
    shutil.copytree(done, run_dir)
    if subprocess.run(["chattr", "+i", str(run_dir)], capture_output=True).returncode:
        shutil.rmtree(d)
        pytest.skip("chattr +i is not available here")
    try:
        yield run_dir
    finally:
        subprocess.run(["chattr", "-i", str(run_dir)], check=False)
        shutil.rmtree(d, ignore_errors=True)


def test_overwrite_into_a_folder_it_cannot_write_deletes_nothing(setup, immutable):
    _, env = setup
    before = tree(immutable)
    rc, _, err = run([*DONE, "--out", str(immutable), "--overwrite"], env)
    line = one_error_line(err)
    assert rc == 1 and "cannot write to output folder" in line, line
    assert tree(immutable) == before  # checkpoints/ and all
    rc, _, err = run([*DONE, "--out", str(immutable), "--resume"], env)
    line = one_error_line(err)
    assert rc == 1 and "cannot write" in line and "unexpected" not in line, line
    assert tree(immutable) == before


def test_overwrite_with_a_bad_value_deletes_nothing(setup, done):
    _, env = setup
    d = copy(done, "bad_overwrite")
    before = tree(d)
    rc, _, err = run([*DONE, "--out", str(d), "--overwrite", "--set", "agent.epsilon=2"], env)
    assert rc == 2 and "agent.epsilon" in one_error_line(err)
    assert tree(d) == before


# ------------------------------------------------------------------ small items


def test_broken_pipe_exits_quietly(setup):
    _, env = setup
    p = subprocess.Popen(vbl_cmd("params", "toy_bandit"), env=env, cwd=REPO,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # the reader is gone before anything is written (`| head -0`)
    err = p.stderr.read().decode()
    p.wait(TIMEOUT)
    assert p.returncode == 141 and err == "", (p.returncode, err)


def test_ascii_output_falls_back_to_plus_minus(setup):
    tmp, env = setup
    rc, out, err = run([*RUN, "--out", str(tmp / "ascii")], dict(env, PYTHONIOENCODING="ascii"))
    assert rc == 0, err[-3000:]
    assert "+-" in out and "±" not in out


def test_sys_exit_at_a_scripts_import_is_an_error(setup):
    tmp, env = setup
    script = tmp / "exits.py"
    script.write_text(EXITS)
    rc, _, err = run(["run", str(script), "--quiet", "--out", str(tmp / "exits")], env)
    line = one_error_line(err)
    assert rc == 1 and "exited while being imported" in line, line
    assert not (tmp / "exits").exists()


@pytest.mark.parametrize("values,says", [("0.1,0.1", "0.1 twice (0.1 and 0.1)"),
                                         ("0.1,0.2,1e-1", "0.1 twice (0.1 and 1e-1)")])
def test_duplicate_sweep_values_are_an_error(setup, values, says):
    tmp, env = setup
    rc, _, err = run([*RUN, "--sweep", f"agent.epsilon={values}", "--out", str(tmp / "dup")],
                     env)
    line = one_error_line(err)
    assert rc == 2 and says in line, line
    assert not (tmp / "dup").exists()


def test_bad_input_exits_2(setup):
    tmp, env = setup
    cores = len(os.sched_getaffinity(0))
    for value in ("0", "abc", "-3", str(4 * cores + 1), "100000"):
        t0 = time.monotonic()
        rc, _, err = run(["list"], dict(env, VBL_HOST_DEVICES=value), timeout=60)
        line = one_error_line(err)
        assert rc == 2 and f"[1, {4 * cores}]" in line, (value, line)
        assert time.monotonic() - t0 < 30
    rc, _, err = run(["list"], dict(env, VBL_HOST_DEVICES=str(4 * cores)), timeout=60)
    assert rc == 0, err
    rc, _, err = run(["reproduce", "--only", "no_such", "--out", str(tmp / "r")], env)
    assert rc == 2 and "unknown paper experiment" in one_error_line(err)


def test_empty_home_writes_nothing_outside_the_cache_folder(setup):
    tmp, env = setup
    watched = [Path("/.cache"), Path("/.config"), Path("/.local")]

    def files():
        return {str(p) for w in watched if w.exists() for p in w.rglob("*")}

    before = files()
    rc, _, err = run([*RUN, "--out", str(tmp / "home")], dict(env, HOME=""), cwd=tmp)
    assert rc == 0, err[-3000:]
    assert files() == before


def test_report_links_are_url_encoded(setup):
    tmp, env = setup
    folder = tmp / "my run (1) #2"
    rc, _, err = run(["run", "bounded_toy", "--quiet", "--out", str(folder)], env)
    assert rc == 0, err[-3000:]
    rc, out, err = run(["report", str(folder)], env, cwd=tmp)
    assert rc == 0, err[-3000:]
    assert "[my run (1) #2](my%20run%20%281%29%20%232/report.md)" in out, out


# ------------------------------------------------------------------ two guards


def test_float32_bounds_checked_on_the_rounded_value(setup):
    """1 - 1e-9 < 1 in float64, but it rounds to 1.0 in float32 (the program's dtype)."""
    tmp, env = setup
    rc, _, err = run(["run", "bounded_toy", "--set", "agent.share=0.999999999", "--quiet",
                      "--out", str(tmp / "f32")], env)
    line = one_error_line(err)
    assert rc == 2 and "rounds to 1.0 in float32" in line and "< 1.0" in line, line
    assert not (tmp / "f32").exists()
    rc, _, err = run(["run", "bounded_toy", "--set", "agent.share=0.9999", "--quiet",
                      "--out", str(tmp / "f32_ok")], env)
    assert rc == 0, err[-3000:]


ESTIMATE_FACTOR = 1.1
"""The memory estimate's state per learner is within this factor of the bytes of the
carry a run actually allocates (it counts every carry leaf's bytes; its KiB are shown to
one decimal)."""


def test_memory_estimate_counts_bytes_of_the_allocated_state(setup, done):
    """The refusal of an oversized run states the state per learner; a small run of the
    same config checkpoints every learner's carry, whose bytes per learner are what the
    program allocated (the estimate counting elements instead of bytes is 4x too small)."""
    tmp, env = setup
    arms = ["--set", "env.num_arms=1000", "--set", "train.pulls_per_chunk=5",
            "--set", "train.num_chunks=2", "--quiet"]
    rc, _, err = run(["run", "toy_bandit", *arms, "--seeds", "4", "--out",
                      str(tmp / "mem")], env)
    assert rc == 0, err[-3000:]
    rc, _, err = run(["run", "toy_bandit", *arms, "--seeds", "2000000000", "--out",
                      str(tmp / "mem_big")], env)
    line = one_error_line(err)
    m = re.search(r"learners x ([0-9.]+) (B|KiB|MiB) state each", line)
    assert rc == 1 and m, line
    estimated = float(m.group(1)) * {"B": 1, "KiB": 1024, "MiB": 2**20}[m.group(2)]
    import orbax.checkpoint as ocp

    state = ocp.PyTreeCheckpointer().restore(str(tmp / "mem" / "checkpoints" / "2" / "state"))
    leaves = [np.asarray(x) for x in state.values()]
    assert all(x.shape[0] == 4 for x in leaves)  # one row per learner
    actual = sum(x.nbytes for x in leaves) / 4
    assert actual > 8000  # 2 x 1000 float32 + a key
    assert actual / ESTIMATE_FACTOR <= estimated <= actual * ESTIMATE_FACTOR, (estimated, actual)
