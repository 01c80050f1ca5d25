"""Traced programs kept on disk: a warm run of unchanged code and config skips tracing.

JAX's persistent compilation cache keeps the compiled programs, but each run still traces
them (Python -> jaxpr -> StableHLO). :func:`traced` keeps each engine program's StableHLO
(``jax.export``) in the compilation cache's folder (:data:`TRACES_DIR`), keyed by
:func:`code_key` (the ``vbl`` sources and the versions of :data:`KEY_PACKAGES`), the
program's identity and config, the devices, and the arguments' shapes, dtypes and
shardings. A run calls the exported program, read back or just exported, so a cold and a
warm run compile the same module (one compilation-cache entry, the same results). A file
holds the sha256 of the rest on its first line, then a pickle of the serialized
``Exported`` and a skeleton of the output tree (classes by module and name).

It is on in the ``vbl`` command's processes (:func:`use_trace_cache`) while the
compilation cache is; ``VBL_TRACE_CACHE=0`` turns it off. ``import vbl`` leaves it off.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import io
import os
import pickle
import sys
import tempfile
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vbl.engine import jax_setup

__all__ = ["use_trace_cache", "traced", "code_key", "TRACES_DIR",
           "TRACE_FORMAT", "KEY_PACKAGES"]

TRACES_DIR = "vbl-traces"  #: the traced programs' folder in the compilation cache's folder
TRACE_FORMAT = 1  #: version of the file layout (part of every key)
KEY_PACKAGES = ("jax", "jaxlib", "numpy", "flax", "brax", "optax", "chex")
"""Packages whose versions are part of every key (the programs trace through them)."""

_STATE = {"on": False}
_LOADED: dict[str, Callable] = {}  # key -> the exported program's jitted call, per process


def use_trace_cache() -> None:
    """Keep traced programs on disk in this process (unless ``VBL_TRACE_CACHE=0``)."""
    _STATE["on"] = os.environ.get("VBL_TRACE_CACHE", "1").strip().lower() not in (
        "0", "", "off")


def _folder() -> Path | None:
    """The traced programs' folder; None when the cache is off."""
    where = jax_setup.shared_cache_folder()
    if not _STATE["on"] or not where:
        return None
    return Path(where) / TRACES_DIR


@functools.cache
def code_key(folder: Path | None = None) -> str:
    """sha256 of the ``.py`` files (names and bytes) of ``folder`` (not its subfolders),
    or by default of the ``vbl`` package with the versions of :data:`KEY_PACKAGES` and
    :data:`TRACE_FORMAT`."""
    h = hashlib.sha256(f"format {TRACE_FORMAT}\n".encode())
    if folder is None:
        root = Path(__file__).resolve().parents[1]
        paths = root.rglob("*.py")
        for name in KEY_PACKAGES:
            with contextlib.suppress(metadata.PackageNotFoundError):
                h.update(f"{name} {metadata.version(name)}\n".encode())
    else:
        root = Path(folder)
        paths = root.glob("*.py")
    for path in sorted(paths):
        h.update(f"{path.relative_to(root).as_posix()}\n".encode())
        h.update(hashlib.sha256(path.read_bytes()).digest())
    return h.hexdigest()


def _key(ident: str, leaves: list, in_tree: Any) -> str:
    """The file name of a program: code, identity, input tree, 64-bit types on or off,
    and each argument's shape, dtype, sharding and devices."""
    parts = [code_key(), ident, str(in_tree), jax.default_backend(),
             f"x64 {jax.config.jax_enable_x64}"]
    for x in leaves:
        s = getattr(x, "sharding", None)
        parts.append(f"{x.shape} {x.dtype} {getattr(s, 'spec', None)} "
                     f"{getattr(getattr(s, 'mesh', None), 'shape_tuple', None)} "
                     f"{sorted(d.id for d in s.device_set) if s is not None else None}")
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:40]


def _class(module: str, name: str) -> type:
    """The class ``name`` of the module ``module`` in ``sys.modules`` (KeyError or
    AttributeError when there is none)."""
    obj = sys.modules[module]
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj


class _Pickler(pickle.Pickler):
    """Pickles classes by module and name, found in ``sys.modules`` when read back (an
    experiment script's classes cannot be imported by name). A class that cannot be found
    that way (its module was imported outside ``sys.modules``) raises: such a program is
    not written, as it could never be read back."""

    def persistent_id(self, obj):
        if not isinstance(obj, type):
            return None
        pid = (obj.__module__, obj.__qualname__)
        if _class(*pid) is not obj:
            raise pickle.PicklingError(f"{pid} is not the class found by that name")
        return pid


class _Unpickler(pickle.Unpickler):
    def persistent_load(self, pid):
        return _class(*pid)


def _payload(path: Path) -> bytes | None:
    """The bytes after the first line of ``path``; None when the file is missing,
    truncated or corrupt (its first line, the sha256 of the rest, does not match)."""
    try:
        digest, _, payload = path.read_bytes().partition(b"\n")
    except OSError:
        return None
    return payload if hashlib.sha256(payload).hexdigest().encode() == digest else None


def _read(path: Path) -> tuple[jax.export.Exported, Any] | None:
    """The exported program and its output tree's skeleton in ``path``; None when the
    file cannot be read back (:func:`_payload`)."""
    try:
        payload = _payload(path)
        if payload is None:
            return None
        blob, skeleton = _Unpickler(io.BytesIO(payload)).load()
        return jax.export.deserialize(bytearray(blob)), skeleton
    except Exception:  # noqa: BLE001 - an unreadable file is traced again
        return None


def _write(path: Path, exported: jax.export.Exported, skeleton: Any) -> None:
    """The exported program and its output tree's skeleton to ``path``
    (:func:`_write_payload`)."""
    try:
        buf = io.BytesIO()
        _Pickler(buf).dump((bytes(exported.serialize()), skeleton))
        _write_payload(path, buf.getvalue())
    except Exception:  # noqa: BLE001 - the cache is an optimisation
        pass


def _write_payload(path: Path, payload: bytes) -> None:
    """Write the sha256 of ``payload``, a newline and ``payload`` atomically (a temporary
    file, then ``os.replace``): a reader sees the old file or the whole new one. A file
    that cannot be written is left out."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(hashlib.sha256(payload).hexdigest().encode() + b"\n" + payload)
            os.replace(tmp, path)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    except Exception:  # noqa: BLE001 - the cache is an optimisation
        pass


def _export(fn: Callable, leaves: list, in_tree: Any) -> tuple[jax.export.Exported, Any]:
    """Trace ``fn`` (a ``jax.jit`` function) for the arguments ``leaves`` (flattened by
    ``in_tree``): the exported program of flat leaves and its output tree's skeleton."""
    out, inner = [], fn.__wrapped__  # the function jitted: options only at the top level

    def flat(*xs):
        res = inner(*jax.tree.unflatten(in_tree, xs))
        out_leaves, out_tree = jax.tree.flatten(res)
        out.append(out_tree)
        return out_leaves

    avals = [jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding) for x in leaves]
    exported = jax.export.export(jax.jit(flat))(*avals)
    return exported, jax.tree.unflatten(out[0], [0] * out[0].num_leaves)


def _load_lapack() -> None:
    """Load LAPACK's functions for XLA's CPU linear-algebra kernels: JAX does it when it
    lowers such an operation, which a program read back skips (its kernels would call
    null pointers and crash the process)."""
    from jaxlib import lapack

    lapack.prepare_lapack_call("potrf", np.float64)


def traced(fn: Callable, ident: str, *args: Any) -> Callable:
    """``fn`` (a ``jax.jit`` function of the arrays ``args``) as a jitted call of its
    exported program, read from the cache or traced and written to it; ``fn`` itself
    when the cache is off or the program cannot be exported. ``ident`` names the program
    and its config (the key holds the rest). Calls pass arguments of ``args``' shapes,
    dtypes and shardings."""
    folder = _folder()
    if folder is None:
        return fn
    leaves, in_tree = jax.tree.flatten(args)
    key = _key(ident, leaves, in_tree)
    if key in _LOADED:
        return _LOADED[key]
    path = folder / f"{key}.jaxexport"
    found = _read(path)
    if found is None:
        try:
            found = _export(fn, leaves, in_tree)
        except Exception:  # noqa: BLE001 - not exportable: fn traces (and raises) itself
            return fn
        _write(path, *found)
    _load_lapack()
    exported, skeleton = found
    out_tree = jax.tree.structure(skeleton)

    def call(*a):
        return jax.tree.unflatten(out_tree, exported.call(*jax.tree.leaves(a)))

    _LOADED[key] = jax.jit(call, compiler_options=jax_setup.COMPILER_OPTIONS)
    return _LOADED[key]
