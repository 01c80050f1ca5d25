"""vbl.params: declared fields validate types and bounds and document themselves."""

import jax
import jax.numpy as jnp
import pytest
from flax import struct

from vbl.params import (
    ParamError,
    describe,
    get_path,
    markdown_table,
    param,
    replace_path,
    section,
    static_paths,
    validate,
)


@struct.dataclass
class Inner:
    radius: float = param(0.11, doc="ball radius", unit="m", gt=0.0)
    substeps: int = param(4, doc="sub-steps", static=True, ge=1)
    kind: str = param("a", doc="kind", static=True, choices=("a", "b"))


@struct.dataclass
class Outer:
    inner: Inner = section(Inner)
    rate: float = param(0.25, doc="learning rate", gt=0.0, le=1.0, source="P")

    def check(self):
        if self.inner.substeps > 100:
            raise ParamError("inner.substeps must be <= 100 with this rate")


def test_defaults_validate_and_leaves_are_traced_fields_only():
    cfg = validate(Outer())
    leaves = jax.tree_util.tree_leaves(cfg)
    assert leaves == [0.11, 0.25]
    assert static_paths(cfg) == ["inner.substeps", "inner.kind"]


def test_replace_path_converts_int_to_float_and_keeps_other_fields():
    cfg = replace_path(Outer(), "inner.radius", 2)
    assert cfg.inner.radius == 2.0 and isinstance(cfg.inner.radius, float)
    assert cfg.rate == 0.25 and get_path(cfg, "inner.kind") == "a"


@pytest.mark.parametrize(
    "path, value, words",
    [
        ("inner.nope", 1.0, ["unknown", "nope", "radius", "substeps"]),
        ("inner.radius", -1.0, ["inner.radius", "> 0"]),
        ("inner.substeps", 1.5, ["inner.substeps", "int"]),
        ("inner.kind", "c", ["one of", "'a'"]),
        ("rate", "fast", ["rate", "float"]),
        ("rate", float("nan"), ["finite"]),
        ("inner", 3, ["section"]),
        ("", 3, ["bad parameter path"]),
    ],
)
def test_bad_overrides_say_what_is_wrong(path, value, words):
    with pytest.raises(ParamError) as err:
        replace_path(Outer(), path, value)
    for w in words:
        assert w in str(err.value)


def test_validate_checks_swept_arrays_elementwise_and_cross_field_rules():
    validate(Outer(rate=jnp.array([0.1, 0.5, 1.0])))
    with pytest.raises(ParamError, match="rate"):
        validate(Outer(rate=jnp.array([0.1, 1.5])))
    with pytest.raises(ParamError, match="<= 100"):
        validate(Outer(inner=Inner(substeps=101)))


def test_describe_and_markdown_table_document_every_field():
    rows = describe(Outer)
    assert [r["path"] for r in rows] == ["inner.radius", "inner.substeps", "inner.kind", "rate"]
    table = markdown_table(Outer)
    assert "| `inner.radius` | 0.11 | m | C |" in table
    assert "| `rate` | 0.25 |  | P |" in table


def test_vmap_over_a_traced_field():
    cfgs = Outer(rate=jnp.array([0.1, 0.2, 0.3]))
    cfgs = jax.tree.map(lambda x: jnp.broadcast_to(x, (3,)), cfgs)  # static fields untouched
    out = jax.vmap(lambda c: c.rate * c.inner.radius)(cfgs)
    assert out.shape == (3,)


@struct.dataclass
class Checked:
    low: float = param(0.0, doc="lower bound")
    high: float = param(1.0, doc="upper bound")

    def check(self):
        if self.low > self.high:
            raise ParamError("low must be <= high")


@struct.dataclass
class Holder:
    bounds: Checked = section(Checked)


def test_validate_runs_the_check_rules_of_nested_sections():
    validate(Holder())
    with pytest.raises(ParamError, match="low must be <= high"):
        validate(Holder(bounds=Checked(low=2.0, high=1.0)))
