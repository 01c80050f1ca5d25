"""One-line errors for the ``vbl`` command, and XLA's C++ log kept quiet unless asked."""

from __future__ import annotations

import errno
import logging
import os
import re
import sys

__all__ = ["one_line", "quiet_xla_env", "quiet_xla_log", "debug_requested", "quiet_library_noise"]

_DISK = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


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


def _disk_full(x: BaseException) -> str | None:
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
        why = _disk_full(x)
        if why is not None:
            where = f" {x.filename}" if getattr(x, "filename", None) else ""
            return (f"cannot write{where}: {why}; free some space (or raise the file size "
                    f"limit), then continue the run with --resume")
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
        from jaxlib import utils

        utils.absl_set_min_log_level(3)  # the C++ library read the variable at import
    except (ImportError, AttributeError):  # another jaxlib: the variable has to do
        pass


def _unraisable(u) -> None:
    if isinstance(u.exc_value, RuntimeError) and str(u.exc_value) == "Event loop is closed":
        return
    sys.__unraisablehook__(u)


def quiet_library_noise() -> None:
    """Process settings of the ``vbl`` command that keep a failure to its one line: the
    checkpoint library's log (absl, through ``logging``) shows critical messages only (its
    errors reach the command as exceptions), and the ``RuntimeError: Event loop is
    closed`` tracebacks its reads print when one read fails and others finish after it
    are dropped (other unraisable exceptions print as usual)."""
    logging.getLogger("absl").setLevel(logging.CRITICAL)
    sys.unraisablehook = _unraisable
