"""How a ``vbl`` process behaves, set up by the command (never by ``import vbl``): every
usable CPU core as a JAX host device, XLA's log quiet and the compilation cache on, output
that survives its encoding, a ``HOME`` for the caches, and a stopped command's last line."""

from __future__ import annotations

import contextlib
import os
import sys

from vbl.engine.errors import (
    debug_requested,
    finish,
    is_stop_code,
    quiet_library_noise,
    quiet_xla_env,
    quiet_xla_log,
)

__all__ = ["use_all_cores", "usable_cores", "MAX_DEVICES_PER_CORE", "COLLECTIVE_TIMEOUT_S",
           "quiet_xla", "end_process", "safe_streams", "home_for_caches", "quiet_process",
           "rerun_with_quiet_xla", "jax_started", "one_device_hint"]


def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


MAX_DEVICES_PER_CORE = 4
"""``VBL_HOST_DEVICES`` is at most this many host devices per usable CPU core (more only
makes XLA's start slower, by minutes at thousands of devices)."""

COLLECTIVE_TIMEOUT_S = 3600
"""Seconds a host device waits for the others at a collective before XLA aborts the run
(XLA's default, 40 s, aborted full-scale runs on a shared 2-core machine, where one device's
thread can wait that long for a core)."""


def jax_started() -> bool:
    """Whether JAX has made its devices (its first computation, or ``jax.devices()``): from
    then on ``XLA_FLAGS`` no longer changes them."""
    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # another JAX: assume the worst
        return True


def use_all_cores() -> int:
    """Expose every usable CPU core as a JAX host device. The ``vbl`` command calls it
    first; a script calls it before its first JAX computation (``import jax`` before it is
    fine): ``from vbl.engine import use_all_cores; use_all_cores()``.

    Sets ``--xla_force_host_platform_device_count=N`` with N = the cores this process may
    use, or ``VBL_HOST_DEVICES=N`` when given (1: one device, as plain JAX), and, with
    N > 1, the wait at collectives to ``COLLECTIVE_TIMEOUT_S`` unless ``XLA_FLAGS`` sets
    it. The engine shards the learner axis over the N devices (results do not depend on N,
    up to the last-bit effect of the per-device batch size described in docs/engine.md).
    An ``XLA_FLAGS`` that already sets the count wins. Once JAX has started
    (:func:`jax_started`) nothing changes. Returns the count set (0 when nothing was
    changed).
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" in flags or jax_started():
        return 0
    cores = usable_cores()
    raw = os.environ.get("VBL_HOST_DEVICES", "").strip() or str(cores)
    most = MAX_DEVICES_PER_CORE * cores
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if not 1 <= n <= most:  # bad input: one line, exit 2
        print(f"vbl: error: VBL_HOST_DEVICES={raw!r} must be an integer in [1, {most}] "
              f"({MAX_DEVICES_PER_CORE} x the {cores} usable CPU cores)", file=sys.stderr)
        raise SystemExit(2)
    if n == 1:
        return 0
    flags = f"{flags} --xla_force_host_platform_device_count={n}"
    if "xla_cpu_collective_call_terminate_timeout_seconds" not in flags:
        flags += f" --xla_cpu_collective_call_terminate_timeout_seconds={COLLECTIVE_TIMEOUT_S}"
    os.environ["XLA_FLAGS"] = flags.strip()
    return n


_HINTED: list[bool] = []


def one_device_hint() -> str | None:
    """The hint ``run_experiment`` prints once per process when JAX runs on one CPU
    device and more cores are usable, and neither ``VBL_HOST_DEVICES`` nor ``XLA_FLAGS``
    chose the device count (None otherwise, and after the first time)."""
    import jax

    if (_HINTED or jax.default_backend() != "cpu" or jax.local_device_count() != 1
            or "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", "")
            or os.environ.get("VBL_HOST_DEVICES", "").strip()):
        return None
    cores = usable_cores()
    if cores < 2:
        return None
    _HINTED.append(True)
    return (f"vbl: hint: this run uses 1 of the {cores} usable CPU cores; to use them all "
            f"(as `vbl run` does), call vbl.engine.use_all_cores() at the start of the "
            f"script, before its first JAX computation (VBL_HOST_DEVICES=1 keeps one device "
            f"and silences this)")


def quiet_xla() -> None:
    """XLA's log kept quiet, the persistent compilation cache and the trace cache on:
    settings of the ``vbl`` command's process, not of ``import vbl``."""
    from vbl.engine.jax_setup import use_compilation_cache  # imports JAX: not at start-up
    from vbl.engine.trace_cache import use_trace_cache

    quiet_xla_log()
    use_compilation_cache()
    use_trace_cache()


def end_process(code: int, argv: list[str], process: bool = True) -> int:
    """After a failure's ``vbl: error:`` line, nothing more reaches stderr (background
    threads of the checkpoint library can print at interpreter exit); ``--debug`` /
    ``VBL_DEBUG`` keep it. With ``process`` (the command owns the process), a stopped
    command (exit 130 or 143) ends here, its files already closed: a signal can interrupt
    a library call mid-way, and the threads it leaves behind can abort the interpreter's
    teardown (SIGABRT instead of the stop's exit code)."""
    finish(code)
    if code and not ("--debug" in argv or debug_requested()):
        sys.stderr.flush()
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, 2)
        os.close(fd)
    if process and is_stop_code(code):
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        os._exit(code)
    return code


_FALLBACK = {"±": "+-", "×": "x", "≈": "~", "≤": "<=", "≥": ">=", "—": "-", "–": "-",
             "…": "...", "µ": "u", "²": "^2", "→": "->"}


def _ascii_fallback(err: UnicodeEncodeError) -> tuple[str, int]:
    """Codec error handler ``vbl-fallback``: ``±`` as ``+-`` (and a few more), any other
    character the encoding lacks as ``?``."""
    bad = err.object[err.start:err.end]
    return "".join(_FALLBACK.get(ch, "?") for ch in bad), err.end


def safe_streams() -> None:
    """stdout and stderr never fail on a character their encoding lacks
    (``PYTHONIOENCODING=ascii``, a C locale): ``±`` is written ``+-``."""
    import codecs

    try:
        codecs.lookup_error("vbl-fallback")
    except LookupError:
        codecs.register_error("vbl-fallback", _ascii_fallback)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.reconfigure(errors="vbl-fallback")
        except (AttributeError, ValueError, OSError):
            pass


def home_for_caches() -> None:
    """An empty or unset ``HOME`` would put the compilation cache (and the plotting
    library's) under ``/.cache``: ``HOME`` becomes the user's home from the password
    database, or, without one, the compilation cache is off and the plotting library's
    settings go to a temporary folder."""
    if os.environ.get("HOME", "").strip():
        return
    try:
        import pwd

        home = pwd.getpwuid(os.getuid()).pw_dir
    except (ImportError, KeyError, OSError):
        home = ""
    if home and home != "/" and os.path.isdir(home):
        os.environ["HOME"] = home
        return
    import tempfile

    os.environ.setdefault("VBL_JAX_CACHE", "0")
    os.environ.setdefault("MPLCONFIGDIR", tempfile.mkdtemp(prefix="vbl-mpl-"))


def quiet_process(argv: list[str]) -> None:
    """Settings of a ``vbl`` process (not of ``main`` called in-process): output that
    never fails on its encoding, XLA's log level before JAX loads, and no library noise
    after a failure unless debugging."""
    home_for_caches()
    safe_streams()
    quiet_xla_env()
    if "--debug" not in argv:
        if not debug_requested():
            quiet_library_noise()


def _started_with(name: str) -> bool | None:
    """Whether the process started with environment variable ``name`` (None: unknown)."""
    try:
        with open("/proc/self/environ", "rb") as f:
            return any(x.startswith(name.encode() + b"=") for x in f.read().split(b"\0"))
    except OSError:
        return None


def rerun_with_quiet_xla() -> None:
    """``python experiments/x.py``: the script loaded JAX (which sets XLA's log level to 1
    when none is given) before :func:`main_for` could set the level, and XLA reads it when
    it loads; so the script runs again, once, with the level of :func:`quiet_xla_env`.
    Nothing happens when the process started with a level or with ``VBL_XLA_LOGS``, when
    that is unknown, or when ``__main__`` is not a script file."""
    main_file = getattr(sys.modules.get("__main__"), "__file__", None)
    if (_started_with("TF_CPP_MIN_LOG_LEVEL") is not False or "jaxlib" not in sys.modules
            or not main_file or not os.path.isfile(main_file)):
        return
    os.environ.pop("TF_CPP_MIN_LOG_LEVEL", None)
    if not quiet_xla_env():
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, *sys.orig_argv[1:]], dict(os.environ))
