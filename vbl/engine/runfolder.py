"""Run folders: an exclusive lock while a run writes, and a marker listing what vbl wrote.

* ``.vbl-lock``: locked with ``fcntl.flock`` for the life of a run (the OS releases it when
  the process ends, however it ends), so a second writer is refused. The file holds the
  pid of the last run that took it and is never deleted (deleting a lock file lets two
  processes lock two different files). ``vbl reproduce`` locks its output folder the same
  way (:func:`lock_reproduce_folder`) for its whole life: a second reproduce into it, or a
  ``vbl run`` into one of its experiment folders from another process, is refused.
* ``.vbl-run``: JSON ``{"vbl_run": 1, "experiment": name, "files": [...]}``, the top-level
  names vbl wrote. ``--overwrite`` only touches folders that carry it, and removes only
  those names (and their ``.tmp`` siblings); other files stay.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import shutil
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from vbl.engine.errors import EngineError

DEFAULT_CHECKPOINT_EVERY = 10
"""Chunks between a run's checkpoints (and one at the end of each compile group)."""

DEFAULT_LEARNER_BATCH = 4096
"""Most learners in one compiled call of a run (larger groups run in batches of this)."""

__all__ = ["RUN_FORMAT", "check_format", "LOCK", "MARKER", "RunFolder", "open_run_folder",
           "record_files", "is_vbl_run", "check_new_folder", "lock_reproduce_folder",
           "allow_runs_under", "check_fingerprint"]

RUN_FORMAT = 2
"""Version of a run folder's layout and of what its ``config.json`` means (its ``format``
field). vbl reads folders of this version only: a folder of another version is refused
with one line naming both (rerun it with today's code; git keeps the code of older ones)."""

LOCK = ".vbl-lock"
MARKER = ".vbl-run"
# Files the engine itself writes (a legacy folder without a marker is known by these).
ENGINE_FILES = ("config.json", "metrics.jsonl", "summary.json", "checkpoints")


def read_run_spec(folder: Path) -> dict[str, Any]:
    """The ``config.json`` content of run folder ``folder`` (its format checked); an
    EngineError that says what is wrong when it is no run folder or its config is not a
    vbl run's."""
    if not folder.is_dir():
        raise EngineError(f"{folder} is not a run folder (no such folder)")
    if not (folder / "config.json").is_file():
        raise EngineError(f"{folder} is not a run folder (no config.json)")
    try:
        spec = json.loads((folder / "config.json").read_text())
    except (OSError, ValueError) as e:
        raise EngineError(f"{folder}/config.json is unreadable: {e}") from None
    if not isinstance(spec, dict) or "experiment" not in spec:
        raise EngineError(f"{folder}/config.json is not a vbl run's config")
    check_format(spec, folder)
    return spec


def check_format(spec: dict[str, Any], folder: str | Path) -> None:
    """Raise an EngineError unless the ``config.json`` content ``spec`` of ``folder`` has
    format :data:`RUN_FORMAT` (folders written before formats were recorded count as 1)."""
    found = spec.get("format", 1)
    if found != RUN_FORMAT:
        raise EngineError(f"{folder} is a run folder of format {found}; this vbl reads format "
                          f"{RUN_FORMAT} only (rerun it with today's code, or use the vbl "
                          f"version that wrote it)")


def _read_marker(path: Path) -> dict[str, Any] | None:
    try:
        m = json.loads((path / MARKER).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or m.get("vbl_run") != 1 or not isinstance(m.get("files"), list):
        return None
    return m


def is_vbl_run(path: Path) -> bool:
    """True if ``path`` carries vbl's run marker."""
    return _read_marker(Path(path)) is not None


def _write_marker(path: Path, marker: dict[str, Any]) -> None:
    tmp = path / (MARKER + ".tmp")
    tmp.write_text(json.dumps(marker, indent=1) + "\n")
    os.replace(tmp, path / MARKER)


def record_files(path: str | Path, names: Iterable[str]) -> None:
    """Add top-level ``names`` (files vbl wrote into the run folder ``path``) to its marker."""
    path = Path(path)
    marker = _read_marker(path)
    if marker is None:
        return
    new = sorted(set(marker["files"]) | {Path(n).name for n in names})
    if new != marker["files"]:
        _write_marker(path, dict(marker, files=new))


def _entries(path: Path) -> list[str]:
    return sorted(p.name for p in path.iterdir() if p.name != LOCK)


def _contains_cwd(path: Path) -> bool:
    try:
        cwd = Path.cwd().resolve()
    except OSError:
        return False
    p = path.resolve()
    return p == cwd or p in cwd.parents


def _disk_error(e: OSError) -> bool:
    return e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def _cannot_write(path: Path, e: OSError) -> EngineError:
    why = e.strerror or str(e)
    hint = "; free some space" if _disk_error(e) else ""
    return EngineError(f"cannot write to output folder {path}: {why}{hint}")


class RunFolder:
    """A locked run folder; :meth:`record` adds names to its marker, :meth:`release` unlocks
    (the OS unlocks too when the process ends)."""

    def __init__(self, path: Path, fd: int | None, lock_fd: int | None = None):
        self.path = path
        self._fd = fd
        self._lock_fd = lock_fd  # a lock without a marker (a reproduce folder)

    def record(self, *names: str | Path) -> None:
        if self._fd is not None:
            record_files(self.path, [str(n) for n in names])

    def release(self) -> None:
        for fd in (self._fd, self._lock_fd):
            if fd is not None:
                os.close(fd)  # closing the descriptor drops the flock
        self._fd = self._lock_fd = None


def _holder(lock: Path) -> tuple[str, str]:
    """``(pid, kind)`` written in a lock file ("?" when unknown; kind "run" or
    "reproduce")."""
    try:
        words = lock.read_text().split()
    except OSError:
        words = []
    return (words[0] if words else "?"), (words[1] if len(words) > 1 else "run")


def _lock(path: Path, kind: str = "run") -> tuple[int, bool]:
    """Open and flock ``path/.vbl-lock`` (non-blocking) and write our pid (and ``kind``,
    for a reproduce) into it.

    Returns ``(fd, whether the lock file existed)``.
    """
    lock = path / LOCK
    existed = lock.exists()
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as e:
        raise _cannot_write(path, e) from e
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
        os.close(fd)
        if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise _cannot_write(path, e) from e
        pid, holder = _holder(lock)
        what = "folder" if kind == "reproduce" else "run folder"
        raise EngineError(f"{what} {path} is in use by another vbl {holder} (pid {pid}); wait "
                          f"for it to end, or use another --out") from None
    try:  # the pid is informative; writing it and a probe file test the folder
        os.ftruncate(fd, 0)
        os.write(fd, (f"{os.getpid()}" + (f" {kind}" if kind != "run" else "") + "\n").encode())
        _probe(path)
    except OSError as e:
        os.close(fd)
        if not existed:
            lock.unlink(missing_ok=True)
        raise _cannot_write(path, e) from e
    return fd, existed


def _probe(path: Path) -> None:
    """Create and remove a file in ``path`` (a writable lock file in a folder that is not
    writable passes the lock, not this)."""
    probe = path / f".vbl-probe-{os.getpid()}"
    fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    os.close(fd)
    os.unlink(probe)


_ALLOWED: set[str] = set()


def allow_runs_under(path: str | Path) -> None:
    """This process may write run folders inside ``path``, a folder that this process's
    ``vbl reproduce`` (or its parent's) holds locked."""
    _ALLOWED.add(os.path.realpath(path))


def _check_parent(path: Path) -> None:
    """Refuse a run folder inside a folder that a ``vbl reproduce`` of another process holds
    locked (its experiment folders are its own)."""
    parent = Path(os.path.realpath(path)).parent
    lock = parent / LOCK
    if str(parent) in _ALLOWED or not lock.is_file():
        return
    try:
        fd = os.open(lock, os.O_RDONLY)
    except OSError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError as e:
        if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return
        pid, kind = _holder(lock)
        if kind == "reproduce":
            raise EngineError(f"run folder {path} belongs to a vbl reproduce that is running "
                              f"into {path.parent} (pid {pid}); wait for it to end, or use "
                              f"another --out") from None
    finally:
        os.close(fd)  # also drops a shared lock taken


def lock_reproduce_folder(path: Path) -> RunFolder:
    """Lock ``path`` (a ``vbl reproduce`` output folder, which exists) for the caller's
    life: a second reproduce, or a run into one of its folders from another process, is
    refused. The folder's runs may be written by this process and its workers
    (:func:`allow_runs_under`)."""
    fd, _ = _lock(path, "reproduce")
    allow_runs_under(path)
    return RunFolder(path, None, fd)


def _check_removable(path: Path, names: list[str]) -> None:
    """Raise the OSError an ``--overwrite`` would meet half-way: every folder from which
    :func:`_remove_listed` deletes must be writable (checked before anything is deleted)."""
    for n in names:
        if n in (LOCK, MARKER, "", ".", "..") or "/" in n or os.sep in n:
            continue
        for p in (path / n, path / (n + ".tmp")):
            if not p.is_dir() or p.is_symlink():
                continue
            for d, _subdirs, _ in os.walk(p):
                if not os.access(d, os.W_OK | os.X_OK):
                    raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), d)


def _undo(path: Path, created: bool, lock_existed: bool) -> None:
    """Remove what a start that failed before any result created (marker, lock, folder)."""
    for n in (MARKER + ".tmp",) + (() if lock_existed else (MARKER, LOCK)):
        try:
            (path / n).unlink(missing_ok=True)
        except OSError:
            pass
    if created:
        try:
            path.rmdir()
        except OSError:
            pass


def check_new_folder(path: Path, *, resume: bool, overwrite: bool,
                     resumable: bool = True) -> None:
    """Refuse, before anything is written, a folder that a run may not use (``resumable``:
    whether the command offers ``--resume``)."""
    if resume and overwrite:
        raise EngineError("--resume and --overwrite exclude each other")
    if path.exists() and not path.is_dir():
        raise EngineError(f"output folder {path} exists and is not a folder")
    if not path.is_dir() or not _entries(path):
        return
    if overwrite:
        if _contains_cwd(path):
            raise EngineError(f"refusing to --overwrite {path}: it is the current folder or "
                              f"contains it; pick another --out")
        if not is_vbl_run(path):
            raise EngineError(f"refusing to --overwrite {path}: it holds no vbl run (no "
                              f"{MARKER} marker); remove it yourself or pick another --out")
    elif resume:
        if not is_vbl_run(path) and not (path / "config.json").is_file():
            raise EngineError(f"cannot --resume {path}: it holds no vbl run (no {MARKER} "
                              f"marker or config.json); pick another --out")
    else:
        how = "--resume to continue it, " if resumable else ""
        raise EngineError(f"output folder {path} exists and is not empty; use {how}"
                          f"--overwrite to replace it, or another --out")


def open_run_folder(out: str | Path | None, name: str, *, resume: bool, overwrite: bool,
                    primary: bool = True, resumable: bool = True) -> RunFolder:
    """Create (or reuse, for ``resume``) the run folder, lock it and write its marker.

    Never overwrites: an existing non-empty folder needs ``resume`` or ``overwrite``;
    ``overwrite`` only empties folders with vbl's marker, removes only the files the marker
    lists, and never the current folder or one containing it. A folder locked by another
    run is refused. Process 0 alone checks, creates and locks the folder. ``resumable``:
    whether the command offers ``--resume`` (its refusal of a taken folder says so).
    """
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = Path(out) if out is not None else Path("runs") / f"{name}-{stamp}"
    if not primary:
        return RunFolder(path, None)
    _check_parent(path)
    check_new_folder(path, resume=resume, overwrite=overwrite, resumable=resumable)
    created = not path.exists()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise _cannot_write(path, e) from e
    try:
        fd, lock_existed = _lock(path)
    except BaseException:
        if created:
            _undo(path, created, True)
        raise
    folder = RunFolder(path, fd)
    try:
        # The folder may have changed between the checks and the lock: check again.
        check_new_folder(path, resume=resume, overwrite=overwrite, resumable=resumable)
        marker = _read_marker(path)
        if overwrite and marker is not None:
            _check_removable(path, marker["files"])  # nothing deleted if it cannot finish
            _remove_listed(path, marker["files"])
            marker = None
        if marker is None:
            files = [LOCK, MARKER]
            if resume:  # a run folder written before markers existed
                files += [n for n in ENGINE_FILES if (path / n).exists()]
            _write_marker(path, {"vbl_run": 1, "experiment": name, "files": sorted(files)})
    except BaseException as e:
        folder.release()
        if not resume and not overwrite:
            _undo(path, created, lock_existed)
        if isinstance(e, OSError):
            raise _cannot_write(path, e) from e
        raise
    return folder


def _remove_listed(path: Path, names: list[str]) -> None:
    """Delete the marker's names (and their ``.tmp`` siblings) except the lock and marker."""
    for n in names:
        if n in (LOCK, MARKER, "", ".", "..") or "/" in n or os.sep in n:
            continue
        for p in (path / n, path / (n + ".tmp")):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            elif p.exists() or p.is_symlink():
                p.unlink()


# ------------------------------------------------------------------ config.json verified

_TOP = ("format", "experiment", "preset", "quick", "sweep", "seeds", "base_seed")


def _flat(spec: dict[str, Any]) -> dict[str, Any]:
    """``config.json``'s values by name: the top-level ones, then every parameter path."""
    out = {k: spec.get(k) for k in _TOP if k in spec}
    cfg = spec.get("config")
    out.update(cfg if isinstance(cfg, dict) else {})
    return out


def _with(spec: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    new = {k: v for k, v in spec.items() if k != "fingerprint"}
    if key in _TOP:
        new[key] = value
    else:
        new["config"] = dict(new.get("config") or {}, **{key: value})
    return new


def differing(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """The names whose values differ between two ``config.json`` contents (top-level
    fields first, then parameter paths, sorted)."""
    from vbl.engine.config import fingerprint  # imports JAX; the CLI reads this at start

    fa, fb = _flat(a), _flat(b)
    same = lambda k: fingerprint({"v": fa.get(k)}) == fingerprint({"v": fb.get(k)})  # noqa: E731
    top = [k for k in _TOP if (k in fa or k in fb) and not same(k)]
    rest = sorted(k for k in set(fa) | set(fb) if k not in _TOP and not same(k))
    return top + rest


def _show(v: Any) -> str:
    text = json.dumps(v)
    return text if len(text) <= 60 else text[:57] + "..."


def check_fingerprint(spec: dict[str, Any], folder: str | Path,
                      originals: Iterable[dict[str, Any]] = ()) -> None:
    """Raise an EngineError unless ``spec`` (a ``config.json``) still has the values its
    fingerprint was computed from (a hand-edited file would otherwise describe a run that
    never happened). The line names the differing parameters: exactly, when one of
    ``originals`` (values the run may have had, e.g. those a ``--resume`` asks for) has the
    recorded fingerprint; else the single value whose change back to one of
    ``originals``' restores the fingerprint; else the values that differ from
    ``originals``' first (the candidates)."""
    from vbl.engine.config import fingerprint  # imports JAX; the CLI reads this at start

    recorded = spec.get("fingerprint")
    body = {k: v for k, v in spec.items() if k != "fingerprint"}
    if recorded == fingerprint(body):
        return
    where = f"{folder}/config.json"
    fix = "restore it (git keeps committed runs), or rerun"
    if not isinstance(recorded, str):
        raise EngineError(f"{where} has no fingerprint; {fix}")
    originals = [dict(o) for o in originals]
    for o in originals:
        if o.get("fingerprint", fingerprint({k: v for k, v in o.items()
                                                if k != "fingerprint"})) == recorded:
            names = differing(spec, o)
            if names:
                ro, rs = _flat(o), _flat(spec)
                what = ", ".join(f"{k} is {_show(rs.get(k))}, the run had {_show(ro.get(k))}"
                                 for k in names[:4]) + (", ..." if len(names) > 4 else "")
                raise EngineError(f"{where} was changed after the run: {what}; {fix}")
    for o in originals:
        fo = _flat(o)
        for k in differing(spec, o):
            if fingerprint(_with(body, k, fo.get(k))) == recorded:
                raise EngineError(f"{where} was changed after the run: {k} is "
                                  f"{_show(_flat(spec).get(k))}, the run had "
                                  f"{_show(fo.get(k))}; {fix}")
    names = differing(spec, originals[0]) if originals else []
    what = (f"; it differs from the defaults in {', '.join(names[:6])}"
            f"{', ...' if len(names) > 6 else ''}" if names else "")
    raise EngineError(f"{where} does not match its fingerprint: it was changed after the "
                      f"run{what}; {fix}")
