"""Process-wide JAX settings that belong to the ``vbl`` command and the engine, never to
``import vbl``.

* :func:`use_compilation_cache`: keep compiled programs on disk (``~/.cache/vbl/jax``), so
  the second run of an experiment starts at once. The ``vbl`` command and its worker
  processes call it; a library user opts in by calling it. ``VBL_JAX_CACHE=0`` turns it
  off, ``VBL_JAX_CACHE=DIR`` moves it.
* :func:`engine_precision`: the scope in which the engine builds and runs programs. vbl's
  hot paths create float32 / int32 arrays explicitly; identification statistics and the
  on-line learner's regressions are float64, so the engine enables 64-bit types for the
  duration of a run (``jax.enable_x64``, a context manager: the user's own JAX code
  outside a run is untouched).
* :data:`COMPILER_OPTIONS`: the XLA options the engine compiles its programs with.
"""

from __future__ import annotations

import contextlib
import os

import jax

__all__ = ["use_compilation_cache", "engine_precision", "CACHE_MIN_COMPILE_S",
           "COMPILER_OPTIONS"]

CACHE_MIN_COMPILE_S = 1.0  #: s; programs that compile faster are not written to the cache

COMPILER_OPTIONS = {"xla_backend_optimization_level": 1}
"""XLA options of every engine program (``jax.jit(..., compiler_options=...)``, per
program, no global flag): LLVM optimisation level 1 instead of XLA's default 2, which
compiles the largest programs in 10-30 % less CPU time at the same run time, with results
equal to float rounding (the measurements: docs/engine.md, "CLI reference")."""


def _cache_dir() -> str | None:
    raw = os.environ.get("VBL_JAX_CACHE",
                         os.path.join(os.path.expanduser("~"), ".cache", "vbl", "jax"))
    return None if raw.strip().lower() in ("0", "", "off") else raw


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
