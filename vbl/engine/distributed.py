"""Multi-process (multi-host) start-up: ``jax.distributed.initialize`` from flags or
``VBL_COORDINATOR`` / ``VBL_NUM_PROCESSES`` / ``VBL_PROCESS_ID``; with the coordinator
``auto``, JAX detects the coordinator, the process count and this process's id from the
cluster environment (SLURM, Open MPI, Kubernetes, Cloud TPU)."""

from __future__ import annotations

import os

import jax

from vbl.engine.errors import EngineError
from vbl.params import ParamError

__all__ = ["initialize", "process_index", "process_count", "is_primary", "AUTO"]

AUTO = "auto"
"""The coordinator value that lets ``jax.distributed.initialize`` detect the cluster."""

_INITIALIZED = False


def initialize(coordinator: str | None = None, num_processes: int | None = None,
               process_id: int | None = None) -> bool:
    """Join a multi-process run if a coordinator is given (flag or env var).

    Must run before any JAX computation. CPU processes use gloo collectives. Returns True
    if a multi-process run was initialised. With ``coordinator="auto"``, what is not given
    comes from JAX's cluster detection (:func:`_auto`).
    """
    coordinator = coordinator or os.environ.get("VBL_COORDINATOR") or None
    if num_processes is None and os.environ.get("VBL_NUM_PROCESSES"):
        num_processes = int(os.environ["VBL_NUM_PROCESSES"])
    if process_id is None and os.environ.get("VBL_PROCESS_ID"):
        process_id = int(os.environ["VBL_PROCESS_ID"])
    if coordinator == AUTO:
        return _auto(num_processes, process_id)
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
    return _start(coordinator, num_processes, process_id)


def _start(coordinator: str | None, num_processes: int | None, process_id: int | None) -> bool:
    global _INITIALIZED
    if _INITIALIZED:
        return True
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                               process_id=process_id)
    _INITIALIZED = True
    return True


def _auto(num_processes: int | None, process_id: int | None) -> bool:
    """``jax.distributed.initialize()`` detecting the cluster: under SLURM the coordinator
    is the job's first node (port from the job id, or ``JAX_COORDINATOR_PORT``), the
    process count ``SLURM_NTASKS`` and the id ``SLURM_PROCID``; Open MPI, Kubernetes
    (with the ``kubernetes`` package) and Cloud TPU likewise; ``JAX_COORDINATOR_ADDRESS``
    names the coordinator anywhere. Where nothing is detected: a ParamError (one line)."""
    try:
        return _start(None, num_processes, process_id)
    except ValueError as e:  # JAX found no cluster: a coordinator, count or id is missing
        raise ParamError(f"--coordinator auto: JAX detected no cluster environment ({e}); "
                          f"run under SLURM, Open MPI, Kubernetes or on Cloud TPU, or give "
                          f"--coordinator HOST:PORT --num-processes N --process-id I") from None


def process_index() -> int:
    return jax.process_index()


def process_count() -> int:
    return jax.process_count()


def is_primary() -> bool:
    return jax.process_index() == 0
