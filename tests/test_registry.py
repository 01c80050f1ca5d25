"""The experiment registry (vbl/engine/registry.py) on throwaway experiment folders: what is
found, loaded once, refused, and how an unknown or broken name is reported."""

from __future__ import annotations

import os
import sys

import pytest

from tests.engine_helpers import TOY
from vbl.engine import registry
from vbl.engine.errors import EngineError
from vbl.params import ParamError

SCRIPT = """from pathlib import Path
from vbl.engine import Experiment, register
from vbl.engine.registry import load_script
toy = load_script({toy!r})
for name in {names!r}:
    register(Experiment(name=name, description="d", default_config=toy.BanditConfig(),
                        make_program=toy.make_program))
"""


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    """An empty registry whose experiment folder is ``tmp_path / "exps"``, with no
    experiment script imported (a script in ``sys.modules`` is not imported, so does not
    register, again); afterwards the registry and the scripts' modules are as before."""
    for name in ("_REGISTRY", "_SOURCES", "_IMPORT_ERRORS"):
        monkeypatch.setattr(registry, name, {})
    monkeypatch.setattr(registry, "_DISCOVERED", set())
    scripts = [m for m in sys.modules if m.startswith("vbl_experiments.")]
    for name in scripts:
        monkeypatch.delitem(sys.modules, name)
    d = tmp_path / "exps"
    d.mkdir()
    monkeypatch.setenv("VBL_EXPERIMENTS_DIR", str(d))
    yield d
    for name in [m for m in sys.modules if m.startswith("vbl_experiments.")]:
        del sys.modules[name]  # then monkeypatch puts the earlier ones back


def _script(folder, stem, *names):
    path = folder / f"{stem}.py"
    path.write_text(SCRIPT.format(toy=str(TOY), names=list(names)))
    return path


def test_the_experiments_dir_variable_lists_folders_by_the_path_separator(monkeypatch):
    monkeypatch.setenv("VBL_EXPERIMENTS_DIR", os.pathsep.join(["a", "", "b/c"]))
    assert [str(p) for p in registry.experiment_dirs()] == ["a", os.path.join("b", "c")]


def test_discover_imports_public_scripts_and_records_broken_ones(fresh):
    _script(fresh, "one", "exp_one")
    _script(fresh, "_helper", "exp_hidden")
    (fresh / "broken.py").write_text("raise RuntimeError('boom')\n")
    found = registry.discover()
    assert sorted(found) == ["exp_one", "toy_bandit"]  # the script loads the toy: its own
    errors = registry.import_errors()
    assert list(errors) == [str((fresh / "broken.py").resolve())]
    assert "RuntimeError: boom" in errors[str((fresh / "broken.py").resolve())]
    with pytest.raises(ParamError, match=r"unknown experiment 'nope'; valid: \['exp_one', "
                                         r"'toy_bandit'\] \(1 script\(s\) failed to "
                                         r"import: broken.py\)"):
        registry.get("nope")
    with pytest.raises(ParamError, match=r"broken.py failed to import: RuntimeError: boom"):
        registry.get("broken")


def test_get_loads_the_script_of_that_name_alone(fresh):
    _script(fresh, "wanted", "wanted")
    (fresh / "other.py").write_text("raise RuntimeError('not imported')\n")
    assert registry.get("wanted").name == "wanted"
    assert registry.import_errors() == {}
    assert registry.source_file("wanted") == str((fresh / "wanted.py").resolve())


def test_a_name_registered_from_two_files_is_refused(fresh):
    _script(fresh, "a", "same")
    _script(fresh, "b", "same")
    registry.load_script(fresh / "a.py")
    with pytest.raises(EngineError, match="experiment name 'same' is registered twice"):
        registry.load_script(fresh / "b.py")


def test_a_script_file_must_register_exactly_one_experiment(fresh, tmp_path):
    one = _script(tmp_path, "one", "solo")
    assert registry.load_experiment_file(one).name == "solo"
    with pytest.raises(EngineError, match=r"registers 2 experiments \(\['x', 'y'\]\)"):
        registry.load_experiment_file(_script(tmp_path, "two", "x", "y"))
    with pytest.raises(EngineError, match="registers no experiment"):
        registry.load_experiment_file(_script(tmp_path, "none"))
    with pytest.raises(ParamError, match="no experiment script"):
        registry.load_experiment_file(tmp_path / "missing.py")
    (tmp_path / "exits.py").write_text("import sys\nsys.exit(3)\n")
    with pytest.raises(EngineError, match=r"failed to import: .*sys.exit\(3\)"):
        registry.load_experiment_file(tmp_path / "exits.py")
    (tmp_path / "raises.py").write_text("1 / 0\n")
    with pytest.raises(EngineError, match="raises.py failed to import: ZeroDivisionError"):
        registry.load_experiment_file(tmp_path / "raises.py")


def test_a_script_outside_the_experiments_folder_gets_a_module_name_of_its_own(fresh,
                                                                               tmp_path):
    inside = registry._module_name((fresh / "grid.py").resolve())
    outside = registry._module_name((tmp_path / "grid.py").resolve())
    assert inside == "vbl_experiments.grid"
    assert outside.startswith("vbl_experiments.grid_") and outside != inside


def test_a_script_path_is_told_from_an_experiment_name():
    assert registry.is_script_path("mine.py") and registry.is_script_path(f"a{os.sep}b")
    assert not registry.is_script_path("grid_shooting")


def test_register_takes_only_experiments():
    with pytest.raises(TypeError, match="register\\(\\) takes an Experiment, got dict"):
        registry.register({})


def test_a_script_that_failed_to_import_is_imported_again_next_time(fresh, tmp_path):
    path = tmp_path / "flaky.py"
    path.write_text("raise RuntimeError('first')\n")
    for _ in range(2):  # not kept half-imported: the second load fails as the first
        with pytest.raises(RuntimeError, match="first"):
            registry.load_script(path)
    path.write_text("VALUE = 7\n")
    assert registry.load_script(path).VALUE == 7
    assert registry.load_script(path) is registry.load_script(path)  # once imported, kept
