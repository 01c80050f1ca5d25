"""Memory estimate of a run, checked before anything is allocated.

A group's learners all live at once: their carries on the devices (the step's input and
output), a host copy gathered for each checkpoint, and orbax's copy while it writes. The
carry's shape comes from tracing the program's ``init`` (no allocation; the runner traces
the per-device ``init`` it then runs, so a run traces it once), so the estimate is
``learners x carry bytes x CARRY_COPIES`` plus keys and configs, for the largest group.
Temporaries inside a step are not counted (``init`` and ``final`` bound theirs by running
``vbl.engine.runner.ONCE_LEARNER_BATCH`` learners per device at once): the estimate is a
floor with a margin, meant to refuse runs that cannot fit, not to promise that others do.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vbl.engine.config import traced_dtype
from vbl.engine.errors import EngineError

__all__ = ["MemoryError_", "CARRY_COPIES", "available_memory", "estimate", "check_memory",
           "check_bytes", "tree_bytes", "fmt_bytes"]

CARRY_COPIES = 4  #: carries held at once per learner (step in + out, host gather, save)
MEMINFO = Path("/proc/meminfo")  #: the kernel's memory counters (MemAvailable)
CGROUP_DIR = Path("/sys/fs/cgroup")  #: this process's cgroup v2 (memory.max, memory.current)


class MemoryError_(EngineError):  # noqa: N801 - not the builtin MemoryError
    """A run's memory estimate exceeds the memory available."""


def fmt_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError


def _meminfo_available() -> int | None:
    try:
        for line in MEMINFO.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_available() -> int | None:
    """Room left under a cgroup v2 memory limit (containers), if there is one."""
    try:
        base = CGROUP_DIR
        limit = (base / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return max(0, int(limit) - int((base / "memory.current").read_text().strip()))
    except (OSError, ValueError):
        return None


def available_memory() -> int:
    """Bytes this process may still allocate: ``MemAvailable`` (or physical memory), capped
    by a cgroup limit."""
    avail = _meminfo_available()
    if avail is None:
        try:
            avail = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            avail = 0
    cg = _cgroup_available()
    return min(avail, cg) if cg is not None else avail


def tree_bytes(tree: Any) -> int:
    """Bytes of the arrays (or shape-dtype structs) of ``tree``."""
    return sum(int(np.prod(x.shape, dtype=object)) * np.dtype(x.dtype).itemsize
               for x in jax.tree_util.tree_leaves(tree))


def _config_structs(group) -> Any:
    """Shape-dtype structs of one learner's config of ``group``."""
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), traced_dtype(x)),
                        group.first_config)


def carry_bytes(group) -> int:
    """Bytes of one learner's state (``init``'s output) of ``group``'s program, from
    ``jax.eval_shape`` of ``init`` on one learner."""
    return tree_bytes(jax.eval_shape(group.program.init, jax.ShapeDtypeStruct((2,), np.uint32),
                                     _config_structs(group)))


def estimate(plan, state_bytes: Callable[[Any], int] = carry_bytes
             ) -> tuple[int, dict[str, Any]]:
    """``(bytes, details)`` for the largest group of ``plan`` (a :class:`SweepPlan`);
    ``state_bytes(group)``: one learner's state in bytes (the runner's traces the program
    it runs: :func:`vbl.engine.runner.run_experiment`)."""
    worst, details = 0, {}
    for g in plan.groups:
        n = g.num_learners
        carry = state_bytes(g) if n else 0
        total = n * (CARRY_COPIES * carry + tree_bytes(_config_structs(g)) + 16)
        if total >= worst:
            worst = total
            details = {"group": g.index, "learners": n, "carry_bytes": carry}
    return worst, details


def check_memory(plan, state_bytes: Callable[[Any], int] = carry_bytes) -> int:
    """Raise :class:`MemoryError_` if :func:`estimate` exceeds :func:`available_memory`;
    return the estimate."""
    need, d = estimate(plan, state_bytes)
    have = available_memory()
    if have and need > have:
        raise MemoryError_(
            f"this run needs about {fmt_bytes(need)} of memory ({d['learners']:,} learners x "
            f"{fmt_bytes(d['carry_bytes'])} state each x {CARRY_COPIES} copies) but "
            f"{fmt_bytes(have)} is available; use fewer --seeds, sweep values or "
            f"environments, or --no-memory-check to try anyway")
    return need


def check_bytes(need: int, what: str, advice: str) -> int:
    """Raise :class:`MemoryError_` (one line: ``what`` ``need`` bytes, what is available,
    ``advice``) if ``need`` exceeds :func:`available_memory`; return ``need``."""
    have = available_memory()
    if have and need > have:
        raise MemoryError_(f"{what} {fmt_bytes(need)} of memory, and {fmt_bytes(have)} is "
                           f"available; {advice}")
    return need
