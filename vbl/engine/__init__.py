"""vbl.engine: experiments as vmapped, sharded, checkpointed programs (see docs/engine.md).

The names below load on first use, so ``import vbl.engine.errors`` (used before JAX
loads) stays free of JAX."""

import importlib

_EXPORTS = {
    "Experiment": "experiment", "Program": "experiment", "ReportSection": "experiment",
    "finish": "experiment",
    "RunContext": "experiment", "RunResult": "experiment", "EngineError": "errors",
    "register": "registry", "get": "registry", "discover": "registry",
    "all_experiments": "registry", "run_experiment": "runner",
    "CheckpointError": "checkpoint", "use_all_cores": "process",
}
__all__ = list(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"vbl.engine.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'vbl.engine' has no attribute {name!r}")
