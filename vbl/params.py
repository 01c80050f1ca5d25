"""Named, documented, validated parameters shared by every part of vbl.

Every physical or algorithmic constant in vbl is a field of a frozen
``flax.struct`` dataclass declared with :func:`param`. A field is either

* **traced** (the default): a pytree leaf, so a sweep can ``vmap`` over it, or
* **static** (``static=True``): part of the tree structure, because it sets an
  array shape or a code path; each distinct value compiles once.

Each field carries metadata (``doc``, ``unit``, ``source`` = ``"P"`` for a fact
from the paper or ``"C"`` for our choice, and bounds), which

* :func:`validate` checks in non-jitted entry points (clear errors, never NaN),
* :func:`describe` turns into the parameter tables of ``docs/``,
* ``vbl.engine`` uses to validate ``--set`` overrides and sweeps.

Example::

    @struct.dataclass
    class BallParams:
        radius: float = param(0.11, doc="ball radius", unit="m", gt=0.0)
        substeps: int = param(10, doc="physics sub-steps", static=True, ge=1)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
from flax import struct

__all__ = [
    "ParamError",
    "param",
    "section",
    "validate",
    "describe",
    "iter_params",
    "get_path",
    "replace_path",
    "static_paths",
]


class ParamError(ValueError):
    """A parameter has a wrong name, type or value; the message says what is allowed."""


def param(
    default: Any,
    *,
    doc: str,
    unit: str = "",
    source: str = "C",
    static: bool = False,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    choices: Sequence[Any] | None = None,
) -> Any:
    """Declare a documented parameter field of a ``flax.struct`` dataclass.

    Args:
      default: default value (a Python scalar, string or tuple).
      doc: one-line description.
      unit: physical unit ("m", "s", "px", "deg", "" for dimensionless).
      source: ``"P"`` (value from the paper) or ``"C"`` (our choice).
      static: True if the value sets a shape or code path (not vmappable).
      ge, gt, le, lt: inclusive / exclusive numeric bounds.
      choices: allowed values (for strings and enumerations).
    """
    if source not in ("P", "C", "P/C"):
        raise ValueError(f"source must be 'P', 'C' or 'P/C', got {source!r}")
    meta = dict(doc=doc, unit=unit, source=source, static=static,
                ge=ge, gt=gt, le=le, lt=lt,
                choices=tuple(choices) if choices is not None else None)
    return struct.field(pytree_node=not static, default=default, metadata=meta)


def section(cls: type, *, doc: str = "") -> Any:
    """A nested parameter group (itself a ``flax.struct`` dataclass) with its defaults."""
    return struct.field(pytree_node=True, default_factory=cls, metadata=dict(doc=doc, section=True))


def _is_params(obj: Any) -> bool:
    return dataclasses.is_dataclass(obj) and not isinstance(obj, type)


def iter_params(obj: Any, prefix: str = "") -> Iterator[tuple[str, dataclasses.Field, Any]]:
    """Yield ``(dotted_path, field, value)`` for every leaf parameter, depth first."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        path = f"{prefix}{f.name}"
        if f.metadata.get("section") or _is_params(value):
            yield from iter_params(value, path + ".")
        else:
            yield path, f, value


def _check_bounds(path: str, value: Any, meta: dict) -> None:
    choices = meta.get("choices")
    if choices is not None:
        if not (np.ndim(value) == 0 and value in choices):
            raise ParamError(f"{path}={value!r} is not allowed; choose one of {list(choices)}")
        return
    if isinstance(value, str) or value is None:
        return
    arr = np.asarray(value)
    if arr.dtype == object or arr.size == 0:
        return
    if arr.dtype.kind in "fc" and not np.all(np.isfinite(arr)):
        raise ParamError(f"{path}={value!r} must be finite")
    checks: list[tuple[str, Callable[[np.ndarray, float], np.ndarray]]] = [
        ("ge", lambda a, b: a >= b), ("gt", lambda a, b: a > b),
        ("le", lambda a, b: a <= b), ("lt", lambda a, b: a < b)]
    symbols = {"ge": ">=", "gt": ">", "le": "<=", "lt": "<"}
    for key, ok in checks:
        bound = meta.get(key)
        if bound is not None and not np.all(ok(arr, bound)):
            raise ParamError(f"{path}={value!r} is out of range: must be {symbols[key]} {bound}"
                             f" ({meta.get('doc', '')})")


def _dtype_kind(value: Any) -> str:
    """NumPy dtype kind of an array-like value ("" for plain Python values)."""
    return np.asarray(value).dtype.kind if hasattr(value, "dtype") else ""


def _is_bool(value: Any) -> bool:
    return isinstance(value, bool | np.bool_) or _dtype_kind(value) == "b"


def _is_int(value: Any) -> bool:
    return (isinstance(value, int | np.integer) and not isinstance(value, bool)
            or _dtype_kind(value) in ("i", "u"))


def _is_number(value: Any) -> bool:
    return (isinstance(value, int | float | np.integer | np.floating)
            and not isinstance(value, bool) or _dtype_kind(value) in ("i", "u", "f"))


_TYPE_RULES = ((bool, _is_bool), (int, _is_int), (float, _is_number),
               (str, lambda v: isinstance(v, str)),
               (tuple, lambda v: isinstance(v, tuple | list) or hasattr(v, "shape")))
"""(type of the default, accepted values), first match wins (bool before int: a bool is an
int to Python)."""


def _check_type(path: str, value: Any, default: Any) -> None:
    """Static fields keep their default's Python type; traced ones may be numbers or arrays."""
    if default is dataclasses.MISSING or default is None:
        return
    accepts = next((rule for kind, rule in _TYPE_RULES if isinstance(default, kind)), None)
    if accepts is not None and not accepts(value):
        raise ParamError(f"{path}={value!r} has type {type(value).__name__}; "
                         f"expected {type(default).__name__}")


def validate(obj: Any, prefix: str = "") -> Any:
    """Check every parameter's type and bounds; return ``obj`` unchanged or raise ParamError.

    Call it from non-jitted entry points (``make_*`` functions, the engine, the CLI).
    Traced fields holding arrays (a sweep) are checked element-wise. The ``check()``
    rules of nested sections run too (innermost first).
    """
    for path, f, value in iter_params(obj, prefix):
        default = f.default
        if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
            default = None
        _check_type(path, value, default)
        _check_bounds(path, value, dict(f.metadata))
    _run_checks(obj)
    return obj


def _run_checks(obj: Any) -> None:
    """Call every ``check()`` cross-field rule, nested sections first."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if _is_params(value):
            _run_checks(value)
    post = getattr(obj, "check", None)
    if callable(post):
        post()


def describe(obj_or_cls: Any, prefix: str = "") -> list[dict[str, Any]]:
    """Rows ``{path, default, unit, source, static, doc, bounds}`` for a docs table."""
    obj = obj_or_cls() if isinstance(obj_or_cls, type) else obj_or_cls
    rows = []
    for path, f, value in iter_params(obj, prefix):
        m = f.metadata
        bounds = []
        for key, sym in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<")):
            if m.get(key) is not None:
                bounds.append(f"{sym} {m[key]}")
        if m.get("choices") is not None:
            bounds.append("one of " + ", ".join(map(str, m["choices"])))
        rows.append(dict(path=path, default=value, unit=m.get("unit", ""),
                         source=m.get("source", "C"), static=bool(m.get("static", False)),
                         doc=m.get("doc", ""), bounds="; ".join(bounds)))
    return rows


def markdown_table(obj_or_cls: Any, prefix: str = "",
                   notes: dict[str, str] | None = None) -> str:
    """A Markdown table of :func:`describe` rows (for ``docs/``); ``notes`` (path -> text)
    are shown in brackets after a row's default."""
    lines = ["| parameter | default | unit | source | static | meaning | allowed |",
             "|---|---|---|---|---|---|---|"]
    for r in describe(obj_or_cls, prefix):
        d = r["default"]
        d = f"{d:g}" if isinstance(d, float) and math.isfinite(d) else d
        if notes and r["path"] in notes:
            d = f"{d} ({notes[r['path']]})"
        lines.append(f"| `{r['path']}` | {d} | {r['unit']} | {r['source']} | "
                     f"{'yes' if r['static'] else ''} | {r['doc']} | {r['bounds']} |")
    return "\n".join(lines)


def _split(path: str) -> list[str]:
    if not path or any(not p for p in path.split(".")):
        raise ParamError(f"bad parameter path {path!r}; use dotted names like 'env.ball_radius'")
    return path.split(".")


def get_path(obj: Any, path: str) -> Any:
    """Value at a dotted path; unknown names list the valid ones."""
    cur = obj
    walked = []
    for name in _split(path):
        names = [f.name for f in dataclasses.fields(cur)] if _is_params(cur) else []
        if name not in names:
            where = ".".join(walked) or "<root>"
            raise ParamError(f"unknown parameter {path!r}: {where} has no field {name!r}; "
                             f"valid: {sorted(names)}")
        cur = getattr(cur, name)
        walked.append(name)
    return cur


def replace_path(obj: Any, path: str, value: Any, _prefix: str = "") -> Any:
    """Return a copy of ``obj`` with the dotted ``path`` set to ``value`` (validated)."""
    names = _split(path)
    if not _prefix:
        get_path(obj, path)  # raises with the valid names
    head, rest = names[0], names[1:]
    if rest:
        inner = replace_path(getattr(obj, head), ".".join(rest), value, f"{_prefix}{head}.")
        return obj.replace(**{head: inner})
    path = _prefix + path
    f = next(f for f in dataclasses.fields(obj) if f.name == head)
    if f.metadata.get("section"):
        raise ParamError(f"{path!r} is a section; set one of its fields, "
                         f"e.g. {path}.{dataclasses.fields(getattr(obj, head))[0].name}")
    default = None if f.default is dataclasses.MISSING else f.default
    if isinstance(default, float) and isinstance(value, int | np.integer) and not isinstance(
            value, bool):
        value = float(value)
    _check_type(path, value, default)
    _check_bounds(path, value, dict(f.metadata))
    return obj.replace(**{head: value})


def static_paths(obj: Any) -> list[str]:
    """Dotted paths of the static (shape- or code-path-setting) parameters."""
    return [p for p, f, _ in iter_params(obj) if f.metadata.get("static")]
