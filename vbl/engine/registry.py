"""Experiment registry: scripts in ``experiments/*.py`` call :func:`register`; the CLI finds
them with :func:`discover` (the package ``vbl.experiments``, which is the source tree's
``experiments/`` folder in an editable install and a copy of it in ``pip install .``; or
the folders in ``$VBL_EXPERIMENTS_DIR``, separated by ``os.pathsep``), or loads one script
given by its path with :func:`load_experiment_file` (``vbl run path/to/script.py``)."""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import traceback
from pathlib import Path
from types import ModuleType

import vbl
from vbl.engine.errors import EngineError
from vbl.engine.experiment import Experiment
from vbl.params import ParamError

__all__ = ["register", "get", "all_experiments", "discover", "experiment_dirs",
           "import_errors", "load_script", "load_experiment_file", "is_script_path",
           "source_folder", "source_file"]

_REGISTRY: dict[str, Experiment] = {}
_SOURCES: dict[str, str] = {}
_IMPORT_ERRORS: dict[str, str] = {}
_DISCOVERED: set[Path] = set()


def register(experiment: Experiment) -> Experiment:
    """Add ``experiment`` to the registry and return it (re-registering from the same file
    replaces it; the same name from another file is an error)."""
    if not isinstance(experiment, Experiment):
        raise TypeError(f"register() takes an Experiment, got {type(experiment).__name__}")
    frame = sys._getframe(1)
    source = os.path.realpath(frame.f_code.co_filename)
    old = _SOURCES.get(experiment.name)
    if old is not None and old != source:
        raise EngineError(f"experiment name {experiment.name!r} is registered twice: "
                          f"{old} and {source}")
    _REGISTRY[experiment.name] = experiment
    _SOURCES[experiment.name] = source
    return experiment


def source_file(name: str) -> str | None:
    """The script that registered experiment ``name`` (None: registered from other code)."""
    return _SOURCES.get(name)


def source_folder(name: str) -> Path:
    """``<source tree>/<name>`` (e.g. ``benchmarks``) beside the installed package (an
    editable install), else
    ``./<name>`` when the package is installed elsewhere (``pip install .``) and the
    current folder holds one (run from the source tree)."""
    beside = Path(vbl.__file__).resolve().parents[1] / name
    if beside.is_dir():
        return beside
    try:
        here = Path.cwd() / name
    except OSError:  # the current folder was removed
        return beside
    return here if here.is_dir() else beside


def experiment_dirs() -> list[Path]:
    """Folders searched for experiment scripts: ``$VBL_EXPERIMENTS_DIR``, else the
    ``experiments/`` folder of the source tree that ``vbl`` was imported from (a checkout),
    else the folder of the installed package ``vbl.experiments`` (``pip install .``)."""
    env = os.environ.get("VBL_EXPERIMENTS_DIR")
    if env:
        return [Path(p) for p in env.split(os.pathsep) if p]
    if getattr(vbl, "__file__", None) is None:  # a namespace package: a bare vbl/ folder
        shadow = ", ".join(str(Path(p).resolve()) for p in getattr(vbl, "__path__", []))
        raise EngineError(f"a folder named vbl ({shadow}) hides the installed vbl package; "
                          "run from another folder or rename that one")
    beside = Path(vbl.__file__).resolve().parents[1] / "experiments"
    if (beside / "__init__.py").is_file():
        return [beside]
    spec = importlib.util.find_spec("vbl.experiments")
    return [Path(p) for p in spec.submodule_search_locations]


def discover() -> dict[str, Experiment]:
    """Import every ``*.py`` (not starting with ``_``) in :func:`experiment_dirs` once.

    A script that fails to import is recorded (see :func:`import_errors`) and skipped.
    """
    for d in experiment_dirs():
        if not d.is_dir():
            continue
        for path in sorted(d.glob("*.py")):
            path = path.resolve()
            if path.name.startswith("_") or path in _DISCOVERED:
                continue
            if str(path) in _SOURCES.values():  # already registered (e.g. run standalone)
                _DISCOVERED.add(path)
                continue
            _DISCOVERED.add(path)
            try:
                load_script(path)
            except Exception as e:  # noqa: BLE001 - one broken script must not hide the others
                _IMPORT_ERRORS[str(path)] = "".join(
                    traceback.format_exception_only(type(e), e)).strip()
    return dict(_REGISTRY)


def _module_name(path: Path) -> str:
    """``vbl_experiments.<stem>`` for a script in an experiments folder (the name
    :func:`discover` and sibling scripts share); a script elsewhere gets its path's hash too,
    so a user's ``grid_shooting.py`` is never taken for the built-in one."""
    if any(path.parent == d.resolve() for d in experiment_dirs()):
        return f"vbl_experiments.{path.stem}"
    digest = hashlib.sha256(str(path).encode()).hexdigest()[:10]
    return f"vbl_experiments.{path.stem}_{digest}"


def load_script(path: str | Path) -> ModuleType:
    """Import the experiment script ``path`` once and return it: as module
    ``vbl_experiments.<stem>`` when it lies in an experiments folder (the name
    :func:`discover` uses), else under a name that also holds its path's hash.

    A script that builds on another's settings (Figures 5 and 9 on ``grid_shooting``, Table
    3 on Table 1) loads it with ``load_script(Path(__file__).with_name("x.py"))`` and so
    shares one module, and one registration, with the registry. An import error is
    re-raised and the half-imported module forgotten.
    """
    path = Path(path).resolve()
    name = _module_name(path)
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # dataclasses and pickling look their module up
        try:
            spec.loader.exec_module(module)
        except SystemExit as e:  # sys.exit() at import: an error, not the command's exit
            sys.modules.pop(name, None)
            raise EngineError(f"experiment script {path} exited while being imported "
                              f"(sys.exit({e.code!r})); an experiment script registers "
                              f"experiments, its __main__ block alone may exit") from None
        except Exception:
            sys.modules.pop(name, None)
            raise
    return sys.modules[name]


def is_script_path(text: str) -> bool:
    """Whether ``vbl run TEXT`` names a script file rather than a registered experiment."""
    return text.endswith(".py") or os.sep in text or (os.altsep or os.sep) in text


def load_experiment_file(path: str | Path) -> Experiment:
    """The one experiment the script ``path`` registers (``vbl run path/to/script.py``).

    Only that file is imported (not the other scripts of its folder, nor the built-in
    experiments). Raises ParamError when the file is missing, EngineError when it fails to
    import or registers no experiment or several.
    """
    p = Path(path)
    if not p.is_file():  # bad input: a ParamError (exit 2)
        raise ParamError(f"no experiment script {str(path)!r} (vbl run takes an experiment "
                         f"name from `vbl list` or the path of a .py file)")
    real = os.path.realpath(p)
    try:
        load_script(p)
    except Exception as e:
        msg = "".join(traceback.format_exception_only(type(e), e)).strip().splitlines()[-1]
        raise EngineError(f"{path} failed to import: {msg}") from e
    names = [n for n, src in _SOURCES.items() if src == real]
    if len(names) != 1:
        what = "no experiment" if not names else f"{len(names)} experiments ({names})"
        raise EngineError(f"{path} registers {what}; an experiment script calls "
                          f"vbl.engine.register(Experiment(...)) once")
    return _REGISTRY[names[0]]


def import_errors() -> dict[str, str]:
    """``{script path: error}`` of experiment scripts that failed to import."""
    return dict(_IMPORT_ERRORS)


def all_experiments() -> dict[str, Experiment]:
    return dict(sorted(_REGISTRY.items()))


def _load_named(name: str) -> None:
    """Import ``<name>.py`` of :func:`experiment_dirs` alone, when there is one: the script
    that usually registers experiment ``name`` (a failure is recorded as by
    :func:`discover`, which then skips the file)."""
    if not name.isidentifier() or name.startswith("_"):
        return
    for d in experiment_dirs():
        path = (d / f"{name}.py").resolve()
        if not path.is_file():
            continue
        if path not in _DISCOVERED and str(path) not in _SOURCES.values():
            _DISCOVERED.add(path)
            try:
                load_script(path)
            except Exception as e:  # noqa: BLE001 - as discover(): recorded, then listed
                _IMPORT_ERRORS[str(path)] = "".join(
                    traceback.format_exception_only(type(e), e)).strip()
        return


def get(name: str) -> Experiment:
    """The experiment called ``name`` (the script ``<name>.py`` of the experiment folders
    first, then every script); an unknown name is a ParamError that lists the valid
    ones."""
    if name not in _REGISTRY:
        _load_named(name)
    if name not in _REGISTRY:
        discover()
    if name not in _REGISTRY:
        msg = f"unknown experiment {name!r}; valid: {sorted(_REGISTRY) or '(none)'}"
        broken = [p for p in _IMPORT_ERRORS if Path(p).stem == name]
        if broken:
            msg += f"\n{broken[0]} failed to import: {_IMPORT_ERRORS[broken[0]]}"
        elif _IMPORT_ERRORS:
            msg += f" ({len(_IMPORT_ERRORS)} script(s) failed to import: " + ", ".join(
                Path(p).name for p in _IMPORT_ERRORS) + ")"
        raise ParamError(msg)  # bad input: exit 2
    return _REGISTRY[name]
