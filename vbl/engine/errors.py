"""Errors of the ``vbl`` command: :class:`EngineError` (a run cannot proceed), one-line
messages for every error, signals that stop a run, and XLA's C++ log kept quiet unless
asked."""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import re
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["EngineError", "one_line", "quiet_xla_env", "quiet_xla_log", "debug_requested",
           "quiet_library_noise", "Terminated", "STOP_GRACE_S", "stop_code", "stop_message",
           "install_stop_handlers", "worker_stop_handlers", "on_forced_exit", "new_command",
           "stop_hint",
           "final_line", "finish", "disk_full"]

_DISK = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


class EngineError(RuntimeError):
    """A run cannot proceed (bad folder, bad checkpoint, unknown experiment...); the message
    says what is wrong and what to do."""


def debug_requested() -> bool:
    """True when ``VBL_DEBUG`` is set to something other than 0/false/no/empty."""
    return os.environ.get("VBL_DEBUG", "").strip().lower() not in ("", "0", "false", "no")


def _chain(e: BaseException):
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        yield e
        e = e.__cause__ or e.__context__


def _first_line(text: str) -> str:
    lines = [x.strip() for x in str(text).strip().splitlines() if x.strip()]
    return lines[0] if lines else ""


def disk_full(x: BaseException) -> str | None:
    """The reason when ``x`` is a full disk, quota or file size limit (an OSError, or the
    checkpoint library's error text with ``os_error_code=N``)."""
    if isinstance(x, OSError) and x.errno in _DISK:
        return x.strerror or os.strerror(x.errno)
    m = re.search(r"os_error_code='?(\d+)", str(x))
    if m and int(m.group(1)) in _DISK:
        return os.strerror(int(m.group(1)))
    return "No space left on device" if "No space left on device" in str(x) else None


def one_line(e: BaseException) -> str:
    """A one-line description of an unexpected exception (what failed, and what to do)."""
    for x in _chain(e):
        why = disk_full(x)
        if why is not None:
            where = f" {x.filename}" if getattr(x, "filename", None) else ""
            return (f"cannot write{where}: {why}; free some space (or raise the file size "
                    f"limit), then continue the run with --resume")
    for x in _chain(e):
        if isinstance(x, OSError) and x.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            where = f" {x.filename}" if getattr(x, "filename", None) else ""
            return (f"cannot write{where}: {x.strerror or os.strerror(x.errno)}; make the "
                    f"folder writable or pick another --out")
    for x in _chain(e):
        if isinstance(x, MemoryError):
            return ("out of memory; use fewer --seeds, sweep values or environments "
                    "(the estimate before the run is a floor)")
    msg = _first_line(str(e)) or "(no message)"
    if len(msg) > 400:
        msg = msg[:400] + "..."
    return (f"unexpected {type(e).__name__}: {msg} (run with --debug or VBL_DEBUG=1 for the "
            f"traceback)")


def quiet_xla_env() -> bool:
    """Set ``TF_CPP_MIN_LOG_LEVEL=3`` (XLA's C++ log: fatal errors only) unless
    ``VBL_XLA_LOGS`` asks for the log or ``TF_CPP_MIN_LOG_LEVEL`` is 0 or 1. XLA reads the
    variable when JAX loads, so the command calls this first. Returns whether it is set."""
    if os.environ.get("VBL_XLA_LOGS", "").strip().lower() not in ("", "0", "false", "no"):
        return False
    if os.environ.get("TF_CPP_MIN_LOG_LEVEL", "").strip() in ("0", "1"):
        return False
    os.environ["TF_CPP_MIN_LOG_LEVEL"] = "3"
    return True


def quiet_xla_log() -> None:
    """Keep XLA's C++ log to fatal errors unless asked for.

    Programs loaded from the persistent compilation cache make XLA print error-level lines
    that are harmless here ("cpu_aot_loader.cc ... Target machine feature ... is not
    supported ... could lead to execution errors such as SIGILL"). ``VBL_XLA_LOGS=1``
    keeps XLA's own level (``TF_CPP_MIN_LOG_LEVEL``); so does a ``TF_CPP_MIN_LOG_LEVEL``
    of 0 or 1 (a request for more).
    """
    if not quiet_xla_env():
        return
    try:
        from jaxlib import utils  # this module loads before JAX: only when asked

        utils.absl_set_min_log_level(3)  # the C++ library read the variable at import
    except (ImportError, AttributeError):  # another jaxlib: the variable has to do
        pass


def _unraisable(u) -> None:
    if isinstance(u.exc_value, RuntimeError) and str(u.exc_value) == "Event loop is closed":
        return
    if isinstance(u.exc_value, KeyboardInterrupt):  # a stop swallowed by a callback: the
        return  # stop watchdog ends the process with its one line
    sys.__unraisablehook__(u)


def quiet_library_noise() -> None:
    """Process settings of the ``vbl`` command that keep a failure to its one line: the
    checkpoint library's log (absl, through ``logging``) shows critical messages only (its
    errors reach the command as exceptions), and the ``RuntimeError: Event loop is
    closed`` tracebacks its reads print when one read fails and others finish after it
    are dropped (other unraisable exceptions print as usual)."""
    logging.getLogger("absl").setLevel(logging.CRITICAL)
    sys.unraisablehook = _unraisable


# ------------------------------------------------------------------ signals

class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread as SIGINT's KeyboardInterrupt is (the ``vbl``
    command handles both alike: exit 143 instead of 130)."""


STOP_GRACE_S = 4.0
"""Seconds the main thread has, after the first SIGINT or SIGTERM, to stop by itself; then
a watchdog thread ends the process with the same one line (a compiled program or a
library that swallows the interrupt cannot keep a ``vbl`` command running). A second
signal ends it at once."""

_state: dict[str, Any] = {"raised": False, "final": False, "signal": None}
_hooks: list[Callable[[], None]] = []
_hints: list[Callable[[], str]] = []
_exit_lock = threading.Lock()


def stop_code(e: BaseException | int | None) -> int:
    """The exit code of a stop: 143 for SIGTERM (:class:`Terminated`), 130 for SIGINT."""
    if isinstance(e, int):
        return 128 + e
    return 143 if isinstance(e, Terminated) else 130


def is_stop_code(code: int) -> bool:
    """Whether exit ``code`` is a stop's (SIGINT 130 or SIGTERM 143)."""
    return code in (128 + signal.SIGINT, 128 + signal.SIGTERM)


def stop_message(e: BaseException | None = None) -> str:
    text = str(e) if e is not None else ""
    if text:
        return text
    return "terminated (SIGTERM)" if isinstance(e, Terminated) else "interrupted"


def on_forced_exit(hook: Callable[[], None]) -> Callable[[], None]:
    """Register ``hook`` (e.g. kill worker processes) to run before the watchdog ends the
    process; returns a function that removes it."""
    _hooks.append(hook)
    return lambda: _hooks.remove(hook) if hook in _hooks else None


def stop_hint(hint: Callable[[], str]) -> Callable[[], None]:
    """Register ``hint``, which says how to go on after a stop (the ``--resume`` command):
    the watchdog's forced-exit line ends with ``; <hint()>``, as the line of a command that
    unwinds by itself does (the first hint registered, the outermost command's, is used:
    a ``vbl reproduce`` running a run in its own process names the reproduce's resume).
    Returns a function that removes it."""
    _hints.append(hint)
    return lambda: _hints.remove(hint) if hint in _hints else None


def _hint_tail() -> str:
    """``; <the first hint>``, or "" (none registered, or it failed)."""
    try:
        return f"; {_hints[0]()}" if _hints else ""
    except Exception:  # noqa: BLE001 - the forced-exit line must be written
        return ""


def new_command() -> None:
    """A command starts in this process (``vbl.cli.main``, also when called in-process
    again): no final line printed and no signal seen yet."""
    with _exit_lock:
        _state.update(raised=False, final=False, signal=None)
        _state.pop("code", None)


def final_line(text: str, code: int) -> bool:
    """Print the command's last ``vbl: error:`` line unless the watchdog already did;
    returns whether it was printed."""
    with _exit_lock:
        if _state["final"]:
            return False
        _state["final"] = True
        _state["code"] = code
    print(f"vbl: error: {text}", file=sys.stderr, flush=True)
    return True


def finish(code: int) -> None:
    """The command is done with exit ``code``: a signal from now on no longer raises (the
    watchdog ends a process still running after it with this code)."""
    with _exit_lock:
        if not _state["final"]:
            _state["final"] = True
            _state["code"] = code


def _handler(signum, frame) -> None:
    if _state["raised"] or _state["final"]:  # the watchdog handles the rest
        return
    _state["raised"] = True
    _state["signal"] = signum
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _force_exit(signum: int, why: str) -> None:
    for hook in list(_hooks):
        with contextlib.suppress(Exception):
            hook()
    with _exit_lock:
        code = _state.get("code") if _state["final"] else None
        if code is None:
            _state["final"] = True
            code = 128 + signum
            name = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted"
            with contextlib.suppress(OSError):
                os.write(2, f"vbl: error: {name} ({why}){_hint_tail()}\n".encode())
    os._exit(code)


def _watch(sock) -> None:
    first, count, deadline = None, 0, None
    while True:
        if deadline is not None:
            sock.settimeout(max(0.0, deadline - time.monotonic()))
        try:
            data = sock.recv(64)
        except TimeoutError:
            _force_exit(first, f"stopped after {STOP_GRACE_S:g} s")
            return
        except OSError:
            return
        for b in data:
            if b in (signal.SIGINT, signal.SIGTERM):
                count += 1
                first = first or b
        if count >= 2:
            _force_exit(first, "second signal")
            return
        if count == 1 and deadline is None:
            deadline = time.monotonic() + STOP_GRACE_S


def install_stop_handlers(watchdog: bool = True) -> None:
    """SIGINT raises KeyboardInterrupt and SIGTERM :class:`Terminated` in the main thread
    (the first signal only); with ``watchdog``, a thread ends the process
    :data:`STOP_GRACE_S` seconds after the first signal, or at a second one, if it is still
    running (after the :func:`on_forced_exit` hooks). Call from the main thread of a
    ``vbl`` process (elsewhere it does nothing)."""
    if threading.current_thread() is not threading.main_thread():
        return
    signal.signal(signal.SIGINT, _handler)
    signal.signal(signal.SIGTERM, _handler)
    if not watchdog:
        return
    r, w = socket.socketpair()
    w.setblocking(False)
    signal.set_wakeup_fd(w.fileno(), warn_on_full_buffer=False)
    _state["wakeup"] = (r, w)  # kept open for the process's life
    threading.Thread(target=_watch, args=(r,), name="vbl-stop-watchdog", daemon=True).start()


def worker_stop_handlers() -> None:
    """In a worker process of ``vbl reproduce``: SIGINT ignored (the parent stops the
    workers; Ctrl-C reaches the whole process group), SIGTERM raises :class:`Terminated`
    so that the run unwinds (the parent kills a worker that has not ended soon after)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_handler)


def _worker_handler(signum, frame) -> None:
    if _state["raised"]:  # the first one was swallowed (by a library's callback): go now
        os._exit(128 + signum)
    _state["raised"] = True
    raise Terminated()
