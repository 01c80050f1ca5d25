"""Process-wide JAX settings that belong to the ``vbl`` command and the engine, never to
``import vbl``.

* :func:`use_compilation_cache`: keep compiled programs on disk (``~/.cache/vbl/jax``, a
  folder per kind of CPU), so the second run of an experiment starts at once. The ``vbl``
  command and its worker processes call it; a library user opts in by calling it.
  ``VBL_JAX_CACHE=0`` turns it off, ``VBL_JAX_CACHE=DIR`` moves it.
* :func:`engine_precision`: the scope in which the engine builds and runs programs. vbl's
  hot paths create float32 / int32 arrays explicitly; identification statistics and the
  on-line learner's regressions are float64, so the engine enables 64-bit types for the
  duration of a run (``jax.enable_x64``, a context manager: the user's own JAX code
  outside a run is untouched).
* :data:`COMPILER_OPTIONS`: the XLA options the engine compiles its programs with.
* :func:`execution_turn`: processes on one machine that name the same lock file in
  ``VBL_EXECUTION_LOCK`` (the workers of one ``vbl reproduce``) run their compiled
  programs one at a time, while tracing and compiling side by side.
* :func:`compile_shared`: with the cache on, processes that share it (the shards of a run
  started together on one machine) compile each program once: the first compiles and
  writes the cache while the others wait, then read it.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import platform
import time
from collections.abc import Iterator
from pathlib import Path

import jax

__all__ = ["use_compilation_cache", "machine_key", "engine_precision", "CACHE_MIN_COMPILE_S",
           "COMPILER_OPTIONS", "compile_shared", "program_lock", "COMPILE_WAIT_S",
           "LOCKS_DIR", "shared_cache_folder", "execution_turn", "EXECUTION_LOCK_ENV"]

CACHE_MIN_COMPILE_S = 0.0
"""s; programs that compile faster are not written to the cache. 0: every program is, so a
warm run compiles nothing (JAX's default, 1 s, leaves the many small programs of a run, its
helpers and reductions, to be compiled again by every process)."""

COMPILER_OPTIONS = {"xla_backend_optimization_level": 1}
"""XLA options of every engine program (``jax.jit(..., compiler_options=...)``, per
program, no global flag): LLVM optimisation level 1 instead of XLA's default 2, which
compiles the largest programs in 10-30 % less CPU time at the same run time, with results
equal to float rounding (the measurements: docs/engine.md, "CLI reference")."""


def machine_key(cpuinfo: str | None = None) -> str:
    """``cpu-<hash>`` of this machine's CPU (architecture and instruction-set features, from
    ``cpuinfo``, the text of ``/proc/cpuinfo`` by default). XLA compiles a cached program
    for the CPU it ran on; one read back on a CPU without those features could stop the
    process (SIGILL), so each kind of CPU that shares a home folder keeps programs in a
    cache folder of its own."""
    if cpuinfo is None:
        cpuinfo = ""
        with contextlib.suppress(OSError):
            cpuinfo = Path("/proc/cpuinfo").read_text(errors="replace")
    flags = ""
    for line in cpuinfo.splitlines():
        if line.startswith(("flags", "Features")):
            flags = line.split(":", 1)[1]
            break
    text = " ".join(sorted(flags.split()) + [platform.machine(), platform.processor()])
    return "cpu-" + hashlib.sha256(text.encode()).hexdigest()[:12]


def _cache_dir() -> str | None:
    """The compilation cache's folder: ``VBL_JAX_CACHE`` (default ``~/.cache/vbl/jax``)
    / :func:`machine_key`; None when it is off."""
    raw = os.environ.get("VBL_JAX_CACHE",
                         os.path.join(os.path.expanduser("~"), ".cache", "vbl", "jax"))
    if raw.strip().lower() in ("0", "", "off"):
        return None
    return os.path.join(raw, machine_key())


def use_compilation_cache() -> None:
    """Turn on JAX's persistent compilation cache in ``VBL_JAX_CACHE`` (unless it is off or
    the process already chose a cache folder)."""
    where = _cache_dir()
    if where is not None and not jax.config.jax_compilation_cache_dir:
        jax.config.update("jax_compilation_cache_dir", where)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", CACHE_MIN_COMPILE_S)


def engine_precision() -> contextlib.AbstractContextManager:
    """Context in which the engine plans, compiles and runs an experiment (64-bit types
    enabled, restored on exit)."""
    return jax.enable_x64(True)


COMPILE_WAIT_S = 3600.0
"""Seconds a process waits for another's compilation of the same program before it
compiles the program itself (a compilation of the largest programs takes minutes)."""

LOCKS_DIR = "vbl-locks"  #: the lock files' folder in the compilation cache's folder


@contextlib.contextmanager
def program_lock(path: str | os.PathLike, wait_s: float | None = COMPILE_WAIT_S,
                 poll_s: float = 0.2) -> Iterator[bool]:
    """Hold the exclusive ``flock`` of the file ``path`` (made when missing) in the
    ``with`` block, waiting at most ``wait_s`` seconds for another holder (None: as long as
    it holds it, woken by the kernel when it lets go; a signal interrupts the wait); yields
    whether it is held. A lock that cannot be made or taken (a read-only folder, a file
    system without locks) or that stays taken yields False: the block runs unlocked, as it
    would without the lock. The lock ends with the block, or with the process."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        yield False
        return
    try:
        yield _flock(fd, wait_s, poll_s)
    finally:
        os.close(fd)  # drops the lock


def _flock(fd: int, wait_s: float | None, poll_s: float) -> bool:
    """Take the exclusive ``flock`` of ``fd`` (see :func:`program_lock`); whether held."""
    try:
        if wait_s is None:
            fcntl.flock(fd, fcntl.LOCK_EX)  # PEP 475: a signal's exception ends the wait
            return True
        end = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return True
            except BlockingIOError:
                if time.monotonic() >= end:
                    return False
                time.sleep(poll_s)
    except OSError:
        return False


EXECUTION_LOCK_ENV = "VBL_EXECUTION_LOCK"
"""Environment variable naming the lock file of :func:`execution_turn` (unset: no lock)."""


@contextlib.contextmanager
def execution_turn() -> Iterator[None]:
    """Run the block (a compiled program's run, to its results) holding the exclusive
    ``flock`` of the file ``VBL_EXECUTION_LOCK`` names, waiting for the process that holds
    it; without the variable, or where the lock cannot be made, the block runs at once.

    A program spreads its learners over every core (one host device per core), so two
    processes' programs at once only contend for the cores, and their spinning thread
    pools waste CPU time besides: ``vbl reproduce --quick``'s workers take turns, while
    tracing and compiling (about one core each) go on beside the other's run (a full-scale
    reproduce's workers run side by side, which is faster there). Turns never change
    results, only their order in time. A multi-process run takes no turns (its processes
    wait for each other inside a program)."""
    path = os.environ.get(EXECUTION_LOCK_ENV, "").strip()
    if not path or jax.process_count() > 1:  # a multi-process run's programs wait for peers
        yield
        return
    with program_lock(path, wait_s=None):
        yield


def shared_cache_folder() -> str | None:
    """The compilation cache's folder this process writes and shares with the other
    processes on this machine; None without a cache or in a multi-process run."""
    where = jax.config.jax_compilation_cache_dir
    return where if where and jax.process_count() == 1 else None


def compile_shared(fn, *args) -> None:
    """Compile the jitted ``fn`` for ``args`` (its next call runs the compiled program)
    holding a lock named by the program's hash in the compilation cache's folder: of
    several processes compiling the same program at once, the first compiles it and writes
    it to the cache, the others wait and then read it. Without the cache,
    or in a multi-process run, ``fn`` compiles at its first call as usual."""
    where = shared_cache_folder()
    if not where:
        return
    lowered = fn.lower(*args)
    key = hashlib.sha256(lowered.as_text().encode()).hexdigest()[:32]
    with program_lock(Path(where) / LOCKS_DIR / f"{key}.lock"):
        lowered.compile()
