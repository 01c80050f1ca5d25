"""Helpers for the engine tests: an isolated experiments folder holding only the toy."""

from __future__ import annotations

import os
import subprocess
import sys
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
