"""The Python API does what ``vbl run`` does: ``run_experiment`` writes the same
``report.md``, shows the same progress (the same ``quiet`` rule, a Jupyter kernel
included), and says how to use every core when JAX runs on one CPU device."""

from __future__ import annotations

import os
import sys
import types

import jax
import pytest

from tests.engine_helpers import TINY, TINY_SETS, toy_experiment
from vbl.engine import process, run_experiment

SETS = {**TINY_SETS, "train.num_chunks": 2}


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    yield from toy_experiment(tmp_path_factory.mktemp("api"))


def test_run_experiment_writes_the_report_vbl_run_writes(toy, tmp_path, capsys):
    from vbl.cli import main

    res = run_experiment(toy, sets={**SETS, "train.num_chunks": 1}, seeds=3, base_seed=5,
                         out=tmp_path / "api", quiet=True)
    assert main(["run", "toy_bandit", *TINY, "--set", "train.num_chunks=1", "--seeds", "3",
                 "--seed", "5", "--out", str(tmp_path / "cli"), "--quiet"]) == 0
    api, cli = (tmp_path / "api" / "report.md"), (tmp_path / "cli" / "report.md")
    assert res.out_dir == tmp_path / "api"
    assert api.read_text() == cli.read_text()
    assert "| point |" in api.read_text()
    assert "(report: report.md" in capsys.readouterr().out  # the CLI names it


def test_no_report_when_asked_or_for_a_shard(toy, tmp_path):
    """report=False (``vbl reproduce`` builds its own) and a shard write none."""
    run_experiment(toy, sets=SETS, seeds=2, out=tmp_path / "none", quiet=True, report=False)
    run_experiment(toy, sets=SETS, seeds=2, out=tmp_path / "shard", quiet=True, shard="1/2")
    assert not (tmp_path / "none" / "report.md").exists()
    assert not (tmp_path / "shard" / "report.md").exists()


def _one_device_machine_with_cores(monkeypatch, cores: int = 4) -> None:
    if jax.local_device_count() != 1:
        pytest.skip("needs a process with one JAX device")
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.delenv("VBL_HOST_DEVICES", raising=False)
    monkeypatch.setattr(process, "usable_cores", lambda: cores)
    monkeypatch.setattr(process, "_HINTED", [])


def test_one_device_gives_one_hint_how_to_use_every_core(toy, tmp_path, monkeypatch,
                                                         capsys):
    _one_device_machine_with_cores(monkeypatch)
    run_experiment(toy, sets=SETS, seeds=2, out=tmp_path / "q", quiet=True)
    assert "hint" not in capsys.readouterr().err  # quiet: nothing
    run_experiment(toy, sets=SETS, seeds=2, out=tmp_path / "a", quiet=False)
    run_experiment(toy, sets=SETS, seeds=2, out=tmp_path / "b", quiet=False)
    hints = [x for x in capsys.readouterr().err.splitlines() if x.startswith("vbl: hint:")]
    assert len(hints) == 1, hints  # once per process
    assert "1 of the 4 usable CPU cores" in hints[0]
    assert "vbl.engine.use_all_cores()" in hints[0]


def test_a_chosen_device_count_gives_no_hint(monkeypatch):
    _one_device_machine_with_cores(monkeypatch)
    monkeypatch.setenv("VBL_HOST_DEVICES", "1")
    assert process.one_device_hint() is None
    monkeypatch.delenv("VBL_HOST_DEVICES")
    monkeypatch.setattr(process, "usable_cores", lambda: 1)
    assert process.one_device_hint() is None
    monkeypatch.setattr(process, "usable_cores", lambda: 2)
    assert process.one_device_hint() is not None
    assert process.one_device_hint() is None  # said once


def test_use_all_cores_changes_nothing_once_jax_started(monkeypatch):
    jax.devices()  # JAX has started in this process
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.delenv("VBL_HOST_DEVICES", raising=False)
    assert process.jax_started()
    assert process.use_all_cores() == 0
    assert "XLA_FLAGS" not in os.environ


def test_a_jupyter_kernel_shows_the_progress_bar(monkeypatch):
    from vbl.engine.progress import auto_quiet

    monkeypatch.delenv("CI", raising=False)
    shell = types.SimpleNamespace(config={"IPKernelApp": {}})
    fake = types.SimpleNamespace(get_ipython=lambda: shell)
    monkeypatch.setitem(sys.modules, "IPython", fake)
    assert auto_quiet() is False
    shell.config = {}  # IPython in a terminal: the terminal rule
    assert auto_quiet() is not sys.stderr.isatty()
    monkeypatch.setenv("CI", "true")
    shell.config = {"IPKernelApp": {}}
    assert auto_quiet() is True


def test_get_imports_the_script_named_like_the_experiment_alone(tmp_path):
    """``vbl params X`` and ``vbl run X ...`` import ``X.py`` only (start-up: one script's
    imports, not every experiment's); an unknown name still imports them all to list
    the valid ones."""
    import subprocess

    from tests.engine_helpers import REPO, experiments_dir

    d = experiments_dir(tmp_path)
    (d / "broken.py").write_text("raise RuntimeError('imported')\n")
    code = ("from vbl.engine.registry import get, import_errors\n"
            "get('toy_bandit'); print(len(import_errors()))\n"
            "try:\n    get('nosuch')\nexcept Exception as e:\n    print(e)\n")
    env = dict(os.environ, VBL_EXPERIMENTS_DIR=str(d))
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, text=True,
                         capture_output=True, timeout=300)
    first, *rest = out.stdout.splitlines()
    assert first == "0", out.stderr  # broken.py was not imported
    assert "valid: ['toy_bandit']" in rest[0] and "broken.py" in rest[0], rest


def test_finding_the_experiments_loads_no_checkpoint_library_or_optax():
    """Start-up of ``vbl list``, ``vbl params`` and bad input (docs/engine.md, "Start-up"):
    importing every experiment script leaves orbax and optax to the first run."""
    import subprocess

    from tests.engine_helpers import REPO

    code = ("import sys\nfrom vbl.engine import discover\ndiscover()\n"
            "print(sorted(m for m in ('orbax.checkpoint', 'optax') if m in sys.modules))")
    env = {k: v for k, v in os.environ.items() if k != "VBL_EXPERIMENTS_DIR"}
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, text=True,
                         capture_output=True, timeout=300)
    assert out.stdout.strip() == "[]", (out.stdout, out.stderr[-2000:])
