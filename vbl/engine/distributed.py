"""Multi-process (multi-host) start-up: ``jax.distributed.initialize`` from flags or
``VBL_COORDINATOR`` / ``VBL_NUM_PROCESSES`` / ``VBL_PROCESS_ID``."""

from __future__ import annotations

import os

import jax

from vbl.engine.config import EngineError

__all__ = ["initialize", "process_index", "process_count", "is_primary"]

_INITIALIZED = False


def initialize(coordinator: str | None = None, num_processes: int | None = None,
               process_id: int | None = None) -> bool:
    """Join a multi-process run if a coordinator is given (flag or env var).

    Must run before any JAX computation. CPU processes use gloo collectives. Returns True
    if a multi-process run was initialised.
    """
    global _INITIALIZED
    coordinator = coordinator or os.environ.get("VBL_COORDINATOR") or None
    if num_processes is None and os.environ.get("VBL_NUM_PROCESSES"):
        num_processes = int(os.environ["VBL_NUM_PROCESSES"])
    if process_id is None and os.environ.get("VBL_PROCESS_ID"):
        process_id = int(os.environ["VBL_PROCESS_ID"])
    if coordinator is None:
        if num_processes not in (None, 1) or process_id not in (None, 0):
            raise EngineError("--num-processes/--process-id need --coordinator HOST:PORT "
                              "(or VBL_COORDINATOR)")
        return False
    if num_processes is None or process_id is None:
        raise EngineError("a multi-process run needs --coordinator, --num-processes and "
                          "--process-id (or VBL_COORDINATOR, VBL_NUM_PROCESSES, VBL_PROCESS_ID)")
    if num_processes < 1 or not 0 <= process_id < num_processes:
        raise EngineError(f"--process-id must be in [0, {num_processes - 1}] and "
                          f"--num-processes >= 1; got {process_id} of {num_processes}")
    if _INITIALIZED:
        return True
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                               process_id=process_id)
    _INITIALIZED = True
    return True


def process_index() -> int:
    return jax.process_index()


def process_count() -> int:
    return jax.process_count()


def is_primary() -> bool:
    return jax.process_index() == 0
