"""Run folders: an exclusive lock while a run writes, and a marker listing what vbl wrote.

* ``.vbl-lock``: locked with ``fcntl.flock`` for the life of a run (the OS releases it when
  the process ends, however it ends), so a second writer is refused. The file holds the
  pid of the last run that took it and is never deleted (deleting a lock file lets two
  processes lock two different files).
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

from vbl.engine.config import EngineError

__all__ = ["RUN_FORMAT", "check_format", "LOCK", "MARKER", "RunFolder", "open_run_folder",
           "record_files", "is_vbl_run", "check_new_folder"]

RUN_FORMAT = 2
"""Version of a run folder's layout and of what its ``config.json`` means (its ``format``
field). vbl reads folders of this version only: a folder of another version is refused
with one line naming both (rerun it with today's code; git keeps the code of older ones)."""

LOCK = ".vbl-lock"
MARKER = ".vbl-run"
# Files the engine itself writes (a legacy folder without a marker is known by these).
ENGINE_FILES = ("config.json", "metrics.jsonl", "summary.json", "checkpoints")


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

    def __init__(self, path: Path, fd: int | None):
        self.path = path
        self._fd = fd

    def record(self, *names: str | Path) -> None:
        if self._fd is not None:
            record_files(self.path, [str(n) for n in names])

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None


def _lock(path: Path) -> tuple[int, bool]:
    """Open and flock ``path/.vbl-lock`` (non-blocking) and write our pid into it.

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
        try:
            pid = lock.read_text().strip() or "?"
        except OSError:
            pid = "?"
        raise EngineError(f"run folder {path} is in use by another vbl run (pid {pid}); wait "
                          f"for it to end, or use another --out") from None
    try:  # the pid is informative; writing it is also the folder's write test
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
    except OSError as e:
        os.close(fd)
        if not existed:
            lock.unlink(missing_ok=True)
        raise _cannot_write(path, e) from e
    return fd, existed


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


def check_new_folder(path: Path, *, resume: bool, overwrite: bool) -> None:
    """Refuse, before anything is written, a folder that a run may not use."""
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
        raise EngineError(f"output folder {path} exists and is not empty; use --resume to "
                          f"continue it, --overwrite to replace it, or another --out")


def open_run_folder(out: str | Path | None, name: str, *, resume: bool, overwrite: bool,
                    primary: bool = True) -> RunFolder:
    """Create (or reuse, for ``resume``) the run folder, lock it and write its marker.

    Never overwrites: an existing non-empty folder needs ``resume`` or ``overwrite``;
    ``overwrite`` only empties folders with vbl's marker, removes only the files the marker
    lists, and never the current folder or one containing it. A folder locked by another
    run is refused. Process 0 alone checks, creates and locks the folder.
    """
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = Path(out) if out is not None else Path("runs") / f"{name}-{stamp}"
    if not primary:
        return RunFolder(path, None)
    check_new_folder(path, resume=resume, overwrite=overwrite)
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
        check_new_folder(path, resume=resume, overwrite=overwrite)
        marker = _read_marker(path)
        if overwrite and marker is not None:
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
