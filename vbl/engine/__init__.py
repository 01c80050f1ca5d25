"""vbl.engine: experiments as vmapped, sharded, checkpointed programs (see docs/engine.md)."""

from vbl.engine.config import EngineError
from vbl.engine.experiment import Experiment, Program, ReportSection, RunContext, RunResult
from vbl.engine.registry import all_experiments, discover, get, register

__all__ = [
    "Experiment", "Program", "ReportSection", "RunContext", "RunResult", "EngineError",
    "register", "get", "discover", "all_experiments", "run_experiment", "main_for",
    "CheckpointError",
]


def __getattr__(name):  # lazy: keep `import vbl.engine` light for experiment scripts
    if name == "run_experiment":
        from vbl.engine.runner import run_experiment

        return run_experiment
    if name == "main_for":
        from vbl.cli import main_for

        return main_for
    if name == "CheckpointError":
        from vbl.engine.checkpoint import CheckpointError

        return CheckpointError
    raise AttributeError(f"module 'vbl.engine' has no attribute {name!r}")
