"""Shard the learner axis over every device (all processes) with a 1-D ``NamedSharding``."""

from __future__ import annotations

import math
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

__all__ = ["learner_sharding", "batch_layout", "put", "to_host", "pad_index"]

AXIS = "learners"


def learner_sharding(devices: list | None = None) -> NamedSharding:
    """``NamedSharding`` splitting axis 0 over ``devices`` (default: all global devices)."""
    devs = np.asarray(devices if devices is not None else jax.devices())
    return NamedSharding(Mesh(devs, (AXIS,)), P(AXIS))


def batch_layout(num_learners: int, num_devices: int, max_batch: int) -> tuple[int, int]:
    """``(num_batches, batch_size)``: the fewest batches of at most ~``max_batch`` learners,
    each a multiple of ``num_devices``, covering ``num_learners`` (padding < one row of
    devices per batch)."""
    if max_batch < 1:
        raise ValueError(f"learner batch must be >= 1, got {max_batch}")
    cap = max(num_devices, (max_batch // num_devices) * num_devices)
    nb = math.ceil(num_learners / cap)
    size = math.ceil(math.ceil(num_learners / nb) / num_devices) * num_devices
    return nb, size


def pad_index(num_learners: int, total: int) -> np.ndarray:
    """Indices ``0..n-1`` then copies of learner 0 up to ``total`` (padding)."""
    return np.concatenate([np.arange(num_learners), np.zeros(total - num_learners, np.int64)])


def put(tree: Any, sharding: NamedSharding) -> Any:
    """Place a pytree of global NumPy arrays (identical on every process) on the devices."""
    if jax.process_count() == 1:
        return jax.device_put(tree, sharding)

    def one(x):
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda idx: x[idx])

    return jax.tree.map(one, tree)


def to_host(tree: Any) -> Any:
    """Global NumPy copies of (possibly multi-process sharded) arrays, on every process."""
    if jax.process_count() == 1:
        return jax.tree.map(np.asarray, tree)
    return jax.tree.map(lambda x: np.asarray(multihost_utils.process_allgather(x, tiled=True)),
                        tree)
