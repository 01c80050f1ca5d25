"""Helpers for the engine tests: an isolated experiments folder holding only the toy."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
TOY = REPO / "experiments" / "toy_bandit.py"

# A tiny toy configuration shared by the tests (3 arms, 5 pulls per chunk).
TINY = ["--set", "env.num_arms=3", "--set", "train.pulls_per_chunk=5"]
TINY_SETS = {"env.num_arms": 3, "train.pulls_per_chunk": 5}


def experiments_dir(tmp: Path) -> Path:
    """A folder with only the toy experiment (other experiments are being written)."""
    d = tmp / "experiments"
    d.mkdir(parents=True, exist_ok=True)
    link = d / "toy_bandit.py"
    if not link.exists():
        link.symlink_to(TOY)
    return d


def toy_experiment(tmp: Path):
    """Generator for a module fixture: the registered toy experiment, with
    ``$VBL_EXPERIMENTS_DIR`` pointing at :func:`experiments_dir` until the fixture ends."""
    from vbl.engine.registry import get

    old = os.environ.get("VBL_EXPERIMENTS_DIR")
    os.environ["VBL_EXPERIMENTS_DIR"] = str(experiments_dir(tmp))
    yield get("toy_bandit")
    if old is None:
        os.environ.pop("VBL_EXPERIMENTS_DIR", None)
    else:
        os.environ["VBL_EXPERIMENTS_DIR"] = old


_PAPER_TOY = """
from vbl.engine.registry import load_script
toy = load_script({toy!r})  # once, in sys.modules, as the engine loads scripts
from vbl.engine import Experiment, register
register(Experiment(name="{name}", description="toy paper result {name}",
                    default_config=toy.BanditConfig(), make_program=toy.make_program,
                    quick={quick!r}, quick_seeds=2, paper_result=True))
"""


def write_paper_toy(folder: Path, name: str, chunks: int) -> Path:
    """``folder/<name>.py``: a script registering the toy as paper experiment ``name``,
    whose quick scale is :data:`TINY_SETS` for ``chunks`` chunks on 2 seeds."""
    path = folder / f"{name}.py"
    path.write_text(_PAPER_TOY.format(name=name, toy=str(TOY),
                                      quick={**TINY_SETS, "train.num_chunks": chunks}))
    return path


def env_for(exp_dir: Path, **extra: str) -> dict[str, str]:
    env = dict(os.environ, VBL_EXPERIMENTS_DIR=str(exp_dir), CI="true",
               TF_CPP_MIN_LOG_LEVEL="3", VBL_HOST_DEVICES="1")  # one device: the reference
    env.pop("XLA_FLAGS", None)
    env.update(extra)
    return env


def vbl_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "vbl.cli", *args]


def run_vbl(args: list[str], env: dict[str, str], timeout: float = 300
            ) -> subprocess.CompletedProcess:
    return subprocess.run(vbl_cmd(*args), env=env, cwd=REPO, capture_output=True, text=True,
                          timeout=timeout)


def one_error_line(stderr: str) -> str:
    """The one ``vbl: error:`` line a failing command prints (asserts there is exactly
    one line)."""
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vbl: error: "), stderr[-3000:]
    return lines[0]


def wait_until(done, what: str, proc: subprocess.Popen | None = None,
               timeout: float = 300) -> None:
    """Poll ``done()`` every 0.2 s; fail after ``timeout`` s, or when ``proc`` has exited,
    with ``proc``'s stderr (after stopping it: reading a live process's pipe would block)."""
    end = time.monotonic() + timeout
    while not done():
        if time.monotonic() > end or (proc is not None and proc.poll() is not None):
            err = ""
            if proc is not None:
                if proc.poll() is None:
                    proc.kill()
                err = f" (exit {proc.poll()}): {proc.communicate()[1][-3000:]}"
            raise AssertionError(f"{what} within {timeout} s{err}")
        time.sleep(0.2)


def zero_carry(group):
    """The carries of a compile group's learners (``[learners, ...]``) as the program's
    ``init`` shapes them, every leaf zero: traced with ``jax.eval_shape``, not compiled."""
    import jax
    import numpy as np

    shape = jax.eval_shape(jax.vmap(group.program.init),
                           jax.ShapeDtypeStruct((group.num_learners, 2), np.uint32),
                           jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype),
                                        group.configs))
    return jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), shape)
