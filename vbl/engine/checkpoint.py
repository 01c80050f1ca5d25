"""Checkpoints of every learner's carry with orbax-checkpoint's ``CheckpointManager``.

A checkpoint at global step ``t`` (chunks completed, counted over groups) holds the carry
of all learners of the current group gathered to the host (so a run can resume on another
number of devices) and JSON metadata with the config fingerprint and the sha256 of every
leaf's bytes, compared with the restored arrays (a damaged file is an error, never a
silently different result).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from vbl.engine.errors import EngineError, disk_full

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


def _sha256(x: np.ndarray) -> str:
    a = np.ascontiguousarray(x)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.reshape(-1).view(np.uint8))
    return h.hexdigest()


def _corrupt(where: Path, e: Exception | str, fallback: str) -> CheckpointError:
    if not isinstance(e, str):
        text = _first_line(str(e))
        e = f"{type(e).__name__}: {text[:240]}{'...' if len(text) > 240 else ''}"
    why = e
    return CheckpointError(f"checkpoint at step {where.name} ({where}) is corrupt or "
                           f"unreadable ({why}); {fallback}")


@contextlib.contextmanager
def _naming(where: Path):
    """A full disk (quota, file size limit) met while the checkpoint library writes becomes
    an OSError naming ``where`` (the step's folder): the library's own error names a
    temporary file, or none (:func:`vbl.engine.errors.one_line` then names no file)."""
    try:
        yield
    except Exception as e:
        if isinstance(e, OSError) and e.filename is not None:
            raise
        why = disk_full(e)
        if why is None:
            raise
        code = e.errno if isinstance(e, OSError) and e.errno else _DISK_CODES.get(
            why, errno.ENOSPC)
        raise OSError(code, why, str(where)) from e


_DISK_CODES = {"File too large": errno.EFBIG, "Disk quota exceeded": errno.EDQUOT}


def _first_line(text: str) -> str:
    lines = [x for x in text.strip().splitlines() if x.strip()]
    return lines[0] if lines else ""


class Checkpoints:
    """Save/restore the engine state under ``directory`` (``run/checkpoints``)."""

    def __init__(self, directory: Path, fingerprint: str, max_to_keep: int = 2):
        self.directory = Path(directory).absolute()
        self.fingerprint = fingerprint
        self._writing = self.directory  # the step folder an asynchronous save writes
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

    def _fallback(self, step: int) -> str:
        earlier = [s for s in self._mngr.all_steps() if s < step]
        where = self.directory / str(step)
        if earlier:
            return (f"delete the folder {where} and --resume again to continue from the "
                    f"checkpoint at step {max(earlier)}, or start again with --overwrite")
        return "no earlier checkpoint is kept: start again with --overwrite (or another --out)"

    def save(self, step: int, carry: Any, meta: dict[str, Any]) -> None:
        """Save host (NumPy) ``carry`` at ``step`` (asynchronously; see :meth:`wait`)."""
        state, _ = _to_storable(carry)
        meta = dict(meta, fingerprint=self.fingerprint, step=int(step),
                    sha256={k: _sha256(v) for k, v in state.items()},
                    dtypes={k: str(np.asarray(v).dtype) for k, v in state.items()})
        with _naming(self._writing):  # the save before this one may fail here
            self._mngr.wait_until_finished()
        self._writing = self.directory / str(int(step))
        with _naming(self._writing):
            self._mngr.save(int(step), args=ocp.args.Composite(
                state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)), force=True)

    def check_meta(self, step: int) -> dict[str, Any]:
        """The metadata of ``step``; CheckpointError if unreadable or of another config."""
        where = self.directory / str(step)
        try:
            meta = self._mngr.restore(step, args=ocp.args.Composite(
                meta=ocp.args.JsonRestore()))["meta"]
        except Exception as e:  # noqa: BLE001
            raise _corrupt(where, e, self._fallback(step)) from e
        if not isinstance(meta, dict) or meta.get("fingerprint") != self.fingerprint:
            got = meta.get("fingerprint") if isinstance(meta, dict) else None
            raise CheckpointError(
                f"checkpoint {where} was written by another config (fingerprint {got}, this run "
                f"{self.fingerprint}); resume with the same experiment, --set, --sweep, --seeds, "
                f"--seed and --quick, or start again with --overwrite / another --out")
        return meta

    def restore(self, step: int, like: Any) -> tuple[Any, dict[str, Any]]:
        """Restore the carry at ``step`` into the structure/shapes/dtypes of ``like``.

        Raises CheckpointError for an unreadable checkpoint, a config mismatch, a shape
        mismatch or arrays whose sha256 differs from the one saved with them.
        """
        target, treedef = _to_storable(like)
        where = self.directory / str(step)
        meta = self.check_meta(step)
        dtypes = meta.get("dtypes")  # the library casts on restore: compare before it does
        for k in sorted(target) if isinstance(dtypes, dict) else ():
            if dtypes.get(k) != str(target[k].dtype):
                raise CheckpointError(f"checkpoint {where}: {k} was saved as {dtypes.get(k)}, "
                                      f"this run expects {target[k].dtype}")
        try:
            state = self._mngr.restore(step, args=ocp.args.Composite(
                state=ocp.args.StandardRestore(target)))["state"]
        except Exception as e:  # noqa: BLE001
            raise _corrupt(where, e, self._fallback(step)) from e
        sums = meta.get("sha256")  # absent in checkpoints written before checksums
        leaves = []
        for k in sorted(target):
            got, want = np.asarray(state[k]), target[k]
            if got.shape != want.shape or got.dtype != want.dtype:
                raise CheckpointError(f"checkpoint {where}: {k} has shape {got.shape} "
                                      f"{got.dtype}, expected {want.shape} {want.dtype}")
            if isinstance(sums, dict) and sums.get(k) != _sha256(got):
                raise _corrupt(where, f"{k} does not match the checksum saved with it: the "
                               f"files changed after they were written", self._fallback(step))
            leaves.append(got)
        return jax.tree_util.tree_unflatten(treedef, leaves), meta

    def wait(self) -> None:
        with _naming(self._writing):
            self._mngr.wait_until_finished()

    def close(self) -> None:
        with _naming(self._writing):
            self._mngr.wait_until_finished()
        self._mngr.close()
