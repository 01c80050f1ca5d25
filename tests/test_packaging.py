"""Packaging: the wheel holds every subpackage, and a plain (non-editable) install lists and
runs every experiment from any folder."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib

from tests.engine_helpers import REPO

BUILT_IN = {"fig5_action_based", "fig9_incremental", "grid_shooting", "ppo_comparator",
            "table1_identification", "table2_shoot_pass", "table3_noisy", "toy_bandit"}


def test_the_package_list_names_every_subpackage():
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    on_disk = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "vbl").rglob(
        "__init__.py") if "__pycache__" not in p.parts}
    assert set(cfg["packages"]) == on_disk | {"vbl.experiments"}
    assert cfg["package-dir"] == {"vbl.experiments": "experiments"}
    assert {p.stem for p in (REPO / "experiments").glob("[!_]*.py")} == BUILT_IN


def test_a_plain_install_lists_and_runs_the_experiments(tmp_path):
    src = tmp_path / "src"  # a copy: the build writes build/ beside the sources
    for name in ("vbl", "experiments"):
        shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    site = tmp_path / "site"
    pip = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps",
                          "--target", str(site), str(src)], capture_output=True, text=True,
                         timeout=600)
    assert pip.returncode == 0, pip.stderr[-3000:]
    assert (site / "vbl" / "experiments" / "grid_shooting.py").is_file()
    env = {k: v for k, v in os.environ.items() if not k.startswith("VBL_")}
    env.update(PYTHONPATH=str(site), VBL_JAX_CACHE=str(tmp_path / "cache"))
    work = tmp_path / "elsewhere"
    work.mkdir()

    def vbl(*args):
        return subprocess.run([sys.executable, "-m", "vbl.cli", *args], cwd=work, env=env,
                              capture_output=True, text=True, timeout=600)

    listed = vbl("list")
    assert listed.returncode == 0, listed.stderr[-3000:]
    assert BUILT_IN <= set(listed.stdout.split()) | {w.strip("*") for w in listed.stdout.split()}
    ran = vbl("run", "toy_bandit", "--quick", "--seeds", "2", "--out", str(work / "run"))
    assert ran.returncode == 0, ran.stderr[-3000:]
    assert (work / "run" / "summary.json").is_file()
    where = subprocess.run([sys.executable, "-c", "import vbl; print(vbl.__file__)"], cwd=work,
                           env=env, capture_output=True, text=True)
    assert where.stdout.strip().startswith(str(site))
