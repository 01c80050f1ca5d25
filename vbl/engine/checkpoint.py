"""Checkpoints of every learner's carry with orbax-checkpoint's ``CheckpointManager``.

A checkpoint at global step ``t`` (chunks completed, counted over groups) holds the carry
of all learners of the current group gathered to the host (so a run can resume on another
number of devices) and JSON metadata with the config fingerprint.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from vbl.engine.config import EngineError

__all__ = ["CheckpointError", "Checkpoints"]


class CheckpointError(EngineError):
    """A checkpoint is unreadable or belongs to another config."""


def _to_storable(tree: Any) -> tuple[dict[str, np.ndarray], Any]:
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    out = {}
    for i, x in enumerate(leaves):
        if jax.dtypes.issubdtype(getattr(x, "dtype", np.float32), jax.dtypes.prng_key):
            raise EngineError("the carry holds a typed PRNG key (jax.random.key); keep raw "
                              "uint32 keys (jax.random.PRNGKey / split) in carries")
        out[f"leaf_{i:04d}"] = np.asarray(x)
    return out, treedef


def _corrupt(where: Path, e: Exception) -> CheckpointError:
    return CheckpointError(f"checkpoint {where} is corrupt or unreadable ({type(e).__name__}: "
                           f"{str(e)[:300]}); delete that step folder to resume from an "
                           f"earlier one, or start again with --overwrite")


class Checkpoints:
    """Save/restore the engine state under ``directory`` (``run/checkpoints``)."""

    def __init__(self, directory: Path, fingerprint: str, max_to_keep: int = 2):
        self.directory = Path(directory).absolute()
        self.fingerprint = fingerprint
        options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, save_interval_steps=1,
                                               create=True, cleanup_tmp_directories=True)
        try:
            self._mngr = ocp.CheckpointManager(self.directory, options=options,
                                               item_names=("state", "meta"))
        except Exception as e:  # noqa: BLE001
            raise CheckpointError(f"cannot open the checkpoint folder {self.directory}: "
                                  f"{type(e).__name__}: {e}") from e

    def latest_step(self) -> int | None:
        return self._mngr.latest_step()

    def save(self, step: int, carry: Any, meta: dict[str, Any]) -> None:
        """Save host (NumPy) ``carry`` at ``step`` (asynchronously; see :meth:`wait`)."""
        state, _ = _to_storable(carry)
        meta = dict(meta, fingerprint=self.fingerprint, step=int(step))
        self._mngr.save(int(step), args=ocp.args.Composite(
            state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)), force=True)

    def restore(self, step: int, like: Any) -> tuple[Any, dict[str, Any]]:
        """Restore the carry at ``step`` into the structure/shapes/dtypes of ``like``.

        Raises CheckpointError for an unreadable checkpoint, a config mismatch or a shape
        mismatch.
        """
        target, treedef = _to_storable(like)
        where = self.directory / str(step)
        try:
            meta = self._mngr.restore(step, args=ocp.args.Composite(
                meta=ocp.args.JsonRestore()))["meta"]
        except Exception as e:  # noqa: BLE001
            raise _corrupt(where, e) from e
        if not isinstance(meta, dict) or meta.get("fingerprint") != self.fingerprint:
            got = meta.get("fingerprint") if isinstance(meta, dict) else None
            raise CheckpointError(
                f"checkpoint {where} was written by another config (fingerprint {got}, this run "
                f"{self.fingerprint}); resume with the same experiment, --set, --sweep, --seeds, "
                f"--seed and --quick, or start again with --overwrite / another --out")
        try:
            state = self._mngr.restore(step, args=ocp.args.Composite(
                state=ocp.args.StandardRestore(target)))["state"]
        except Exception as e:  # noqa: BLE001
            raise _corrupt(where, e) from e
        leaves = []
        for k in sorted(target):
            got, want = np.asarray(state[k]), target[k]
            if got.shape != want.shape or got.dtype != want.dtype:
                raise CheckpointError(f"checkpoint {where}: {k} has shape {got.shape} "
                                      f"{got.dtype}, expected {want.shape} {want.dtype}")
            leaves.append(got)
        return jax.tree_util.tree_unflatten(treedef, leaves), meta

    def wait(self) -> None:
        self._mngr.wait_until_finished()

    def close(self) -> None:
        self._mngr.wait_until_finished()
        self._mngr.close()
