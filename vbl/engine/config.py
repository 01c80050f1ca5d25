"""Config helpers: parse ``--set``/``--sweep`` text, apply validated overrides, split static
from traced fields, stack traced leaves along a learner axis, JSON and fingerprints."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import jax
import numpy as np

from vbl.engine.errors import EngineError
from vbl.params import (
    ParamError,
    _check_bounds,
    get_path,
    iter_params,
    replace_path,
    static_paths,
    validate,
)

__all__ = [
    "parse_value", "parse_scalar", "field_default", "parse_assignment", "parse_sweep",
    "split_values", "apply_overrides", "is_static", "config_to_dict", "fingerprint", "stack_traced",
    "traced_dtype", "check_dtypes", "set_value", "json_value", "INT32", "INT64",
]

INT32 = (-2**31, 2**31 - 1)
INT64 = (-2**63, 2**63 - 1)
_F32_MAX = float(np.finfo(np.float32).max)


def field_default(config: Any, path: str) -> Any:
    """The declared default of the field at dotted ``path`` of ``config`` (None without
    one): its type tells how a command-line value is parsed."""
    parent_path, _, name = path.rpartition(".")
    parent = get_path(config, parent_path) if parent_path else config
    f = next(f for f in dataclasses.fields(parent) if f.name == name)
    return None if f.default is dataclasses.MISSING else f.default


def split_values(text: str) -> list[str]:
    """Split ``"0.1,(1,2),abc"`` on commas outside parentheses/brackets."""
    out, depth, cur = [], 0, []
    for ch in text:
        if ch in "([":
            depth += 1
        elif ch in ")]":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur).strip())
    return out


def parse_scalar(text: str) -> Any:
    """A command-line scalar: a bool, an int, a float, or a string (quotes removed)."""
    t = text.strip()
    if t.lower() in ("true", "false"):
        return t.lower() == "true"
    for conv in (int, float):
        try:
            return conv(t)
        except ValueError:
            pass
    if len(t) >= 2 and t[0] == t[-1] and t[0] in "'\"":
        return t[1:-1]
    return t


def parse_value(text: str, default: Any = None) -> Any:
    """Parse one command-line value: bool (true/false), int, float, tuple ``(a,b)`` or str.

    ``default`` (the field's default) guides the parse: a str field keeps the text as is.
    """
    t = text.strip()
    if isinstance(default, str):
        return t
    if (t.startswith("(") and t.endswith(")")) or (t.startswith("[") and t.endswith("]")):
        inner = t[1:-1].strip()
        return tuple(parse_value(x) for x in split_values(inner)) if inner else ()
    if isinstance(default, tuple) and "," in t:
        return tuple(parse_scalar(x) for x in split_values(t))
    return parse_scalar(t)


def parse_assignment(text: str, config: Any) -> tuple[str, Any]:
    """``"env.ball_radius=0.12"`` -> ``("env.ball_radius", 0.12)``, the path checked."""
    if "=" not in text:
        raise ParamError(f"bad override {text!r}: use PATH=VALUE, e.g. agent.learning_rate=0.1")
    path, _, value = text.partition("=")
    path = path.strip()
    get_path(config, path)  # unknown names list the valid ones
    return path, parse_value(value, field_default(config, path))


def parse_sweep(text: str, config: Any) -> tuple[str, list[Any]]:
    """``"agent.learning_rate=0.1,0.25"`` -> ``("agent.learning_rate", [0.1, 0.25])``."""
    if "=" not in text:
        raise ParamError(f"bad sweep {text!r}: use PATH=V1,V2,..., e.g. "
                         f"agent.learning_rate=0.1,0.25,0.5")
    path, _, values = text.partition("=")
    path = path.strip()
    get_path(config, path)
    default = field_default(config, path)
    texts = split_values(values)
    vals = [parse_value(v, default) for v in texts]
    if not vals or any(v == "" for v in vals):
        raise ParamError(f"sweep {text!r} has an empty value")
    seen: dict[str, str] = {}
    for t, v in zip(texts, vals, strict=True):
        key = fingerprint({"v": _same_number(v)})  # 0.1 and 1e-1, 1 and 1.0 are one value
        if key in seen:
            raise ParamError(f"--sweep {path} has the value {v!r} twice ({seen[key]} and "
                             f"{t}); give each value once")
        seen[key] = t
    return path, vals


def _same_number(v: Any) -> Any:
    if isinstance(v, bool):
        return v
    if isinstance(v, int | float):
        return float(v)
    if isinstance(v, tuple | list):
        return [_same_number(x) for x in v]
    return v


def set_value(config: Any, path: str, value: Any) -> Any:
    """:func:`vbl.params.replace_path` whose unexpected errors (a value numpy cannot
    compare, say) become :class:`ParamError` naming the field."""
    try:
        return replace_path(config, path, value)
    except ParamError:
        raise
    except (TypeError, ValueError, ArithmeticError) as e:
        raise ParamError(f"{path}={value!r} is not a valid value: {e}") from None


def apply_overrides(config: Any, overrides: Mapping[str, Any] | Iterable[tuple[str, Any]]
                    ) -> Any:
    """Return ``config`` with every ``path -> value`` set (each validated, also in the dtype
    it will have, see :func:`check_dtypes`), then the whole config validated (its
    ``check()`` rules; an error other than ParamError there becomes a ParamError)."""
    items = overrides.items() if isinstance(overrides, Mapping) else overrides
    for path, value in items:
        config = set_value(config, path, value)
    check_dtypes(config)
    try:
        return validate(config)
    except ParamError:
        raise
    except Exception as e:  # noqa: BLE001 - a check() rule failed in another way
        raise ParamError(f"the config is invalid: {type(e).__name__}: {e}") from None


def _numbers(x: Any) -> bool:
    return isinstance(x, int | float | np.integer | np.floating)


def check_dtypes(config: Any) -> None:
    """Check every number in the dtype it will have in a program.

    Traced ints become int32 and traced floats float32 (:func:`traced_dtype`): an int must
    fit int32, a float must stay finite in float32 and keep its bounds after the cast
    (``gt=0`` with ``1e-50`` rounds to 0). Static ints must fit int64. A tuple whose
    default holds numbers must hold numbers. Raises ParamError.
    """
    statics = set(static_paths(config))
    for path, f, value in iter_params(config):
        _check_number_tuple(path, f, value)
        if isinstance(value, str | bool | np.bool_) or value is None:
            continue
        try:
            a = np.asarray(value)
        except (TypeError, ValueError, OverflowError):
            continue
        if a.dtype == object and a.size and all(isinstance(x, int) for x in a.ravel()):
            lo, hi = INT64
            raise ParamError(f"{path}={value!r} is too large: ints must lie in [{lo}, {hi}]")
        traced = path not in statics
        if a.dtype.kind in "iu":
            _check_int_fits(path, value, a, traced)
        elif a.dtype.kind == "f" and traced:
            _check_float32(path, f, value, a)


def _check_number_tuple(path: str, f: dataclasses.Field, value: Any) -> None:
    """A field whose default is a tuple of numbers holds a tuple (or list) of numbers."""
    default = None if f.default is dataclasses.MISSING else f.default
    if isinstance(default, tuple) and default and all(_numbers(x) for x in default):
        if not isinstance(value, tuple | list) or not all(
                _numbers(x) and not isinstance(x, bool) for x in value):
            raise ParamError(f"{path}={value!r} must be a tuple of numbers, like its "
                             f"default {default!r}")


def _check_int_fits(path: str, value: Any, a: np.ndarray, traced: bool) -> None:
    """Ints ``a`` fit int32 when ``traced``, else int64."""
    lo, hi = INT32 if traced else INT64
    if a.size and (int(a.min()) < lo or int(a.max()) > hi):
        kind = "a traced int (int32 in the program)" if traced else "an int"
        raise ParamError(f"{path}={value!r} does not fit {kind}: allowed "
                         f"[{lo}, {hi}]")


def _check_float32(path: str, f: dataclasses.Field, value: Any, a: np.ndarray) -> None:
    """Traced floats ``a`` stay finite in float32 and keep the field's bounds after the
    cast."""
    finite = np.isfinite(a)
    if np.any(finite & (np.abs(np.where(finite, a, 0.0)) > _F32_MAX)):
        raise ParamError(f"{path}={value!r} does not fit float32 (traced floats are "
                         f"float32 in the program: |x| <= {_F32_MAX:.7g})")
    as32 = a.astype(np.float32)
    try:
        _check_bounds(path, as32, dict(f.metadata))
    except ParamError:
        m = f.metadata
        bounds = ", ".join(f"{sym} {m[k]}" for k, sym in (("ge", ">="), ("gt", ">"),
                           ("le", "<="), ("lt", "<")) if m.get(k) is not None)
        raise ParamError(f"{path}={value!r} rounds to {as32.tolist()!r} in float32 "
                         f"(the program's dtype), outside its range ({bounds})"
                         ) from None


def is_static(config: Any, path: str) -> bool:
    return path in static_paths(config)


def json_value(v: Any) -> Any:
    """``v`` as ``config.json`` holds it: arrays and tuples as lists, NumPy scalars as
    Python ones, other objects as their repr."""
    if isinstance(v, np.ndarray | jax.Array):
        return np.asarray(v).tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, tuple | list):
        return [json_value(x) for x in v]
    if isinstance(v, float | int | str | bool) or v is None:
        return v
    return repr(v)


def config_to_dict(config: Any) -> dict[str, Any]:
    """``{dotted.path: JSON-able value}`` of every parameter."""
    return {p: json_value(v) for p, _, v in iter_params(config)}


def fingerprint(obj: Any) -> str:
    """sha256 of the canonical JSON of ``obj`` (first 16 hex digits)."""
    text = json.dumps(_jsonable_tree(obj), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _jsonable_tree(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _jsonable_tree(v) for k, v in obj.items()}
    return json_value(obj)


def traced_dtype(value: Any) -> np.dtype:
    """float -> float32, int -> int32, bool -> bool (what a program sees)."""
    a = np.asarray(value)
    if a.dtype.kind == "b":
        return np.dtype(bool)
    if a.dtype.kind in "iu":
        return np.dtype(np.int32)
    if a.dtype.kind == "f":
        return np.dtype(np.float32)
    raise ParamError(f"traced parameter value {value!r} (dtype {a.dtype}) cannot be an array; "
                     f"declare the field static=True")


def stack_traced(configs: Sequence[Any], repeats: int = 1) -> Any:
    """Stack the traced leaves of equally-structured configs along a new learner axis.

    Each config is repeated ``repeats`` times (seeds), giving leaves of shape
    ``(len(configs) * repeats, *leaf_shape)`` as NumPy arrays with :func:`traced_dtype`.
    """
    leaves0, treedef = jax.tree_util.tree_flatten(configs[0])
    all_leaves = [leaves0]
    for c in configs[1:]:
        leaves, td = jax.tree_util.tree_flatten(c)
        if td != treedef:
            raise EngineError("sweep points differ in static fields inside one group")
        all_leaves.append(leaves)
    stacked = []
    for i in range(len(leaves0)):
        dt = traced_dtype(leaves0[i])
        col = np.stack([np.asarray(ls[i], dtype=dt) for ls in all_leaves])
        stacked.append(np.repeat(col, repeats, axis=0))
    return jax.tree_util.tree_unflatten(treedef, stacked)
