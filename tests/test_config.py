"""Config helpers (vbl/engine/config.py): command-line values, sweeps given twice, the
dtype checks a value meets before it runs, JSON values, fingerprints and the stacked
learner axis.

Truths: hand-written values, NumPy's float32 and int32 limits."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vbl.engine.config import (
    apply_overrides,
    fingerprint,
    json_value,
    parse_scalar,
    parse_sweep,
    parse_value,
    split_values,
    stack_traced,
    traced_dtype,
)
from vbl.params import ParamError
from vbl.vision.camera import CameraParams


def test_values_split_on_commas_outside_brackets_and_parentheses():
    assert split_values("[1,2],3") == ["[1,2]", "3"]
    assert split_values("((1,2),3), 4") == ["((1,2),3)", "4"]


@pytest.mark.parametrize("text, want", [("TRUE", True), ("3", 3), ("3.0", 3.0),
                                        ("1e3", 1000.0), ("'a b'", "a b"), ('"x"', "x"),
                                        ("abc", "abc"), ("'", "'")])
def test_a_command_line_scalar(text, want):
    got = parse_scalar(text)
    assert got == want and type(got) is type(want)


def test_a_command_line_value_follows_the_fields_default():
    assert parse_value("(1,2)", default="a") == "(1,2)"  # a str field keeps its text
    assert parse_value("()") == () and parse_value("[1, 2.5]") == (1, 2.5)
    assert parse_value("1,2", default=(0, 0)) == (1, 2)  # a tuple field: bare commas
    assert parse_value("1,2", default=0.5) == "1,2"


def test_a_sweep_value_given_twice_is_refused_in_any_spelling():
    from vbl.engine import get

    cfg = get("grid_shooting").default_config
    path = "agent.lem.initial_difficulty"
    assert parse_sweep(f"{path}=0.1,0.2", cfg) == (path, [0.1, 0.2])
    for twice in ("0.1,1e-1", "1,1.0"):
        with pytest.raises(ParamError, match="twice"):
            parse_sweep(f"{path}={twice}", cfg)


@pytest.mark.parametrize("sets, says", [
    ({"hfov_deg": 1e-50}, "rounds to 0.0 in float32"),          # gt=0 lost in float32
    ({"pixel_noise_std": 1e39}, "does not fit float32"),
    ({"image_width": 2**31}, "does not fit a traced int"),
])
def test_values_are_checked_in_the_dtype_the_program_gives_them(sets, says):
    with pytest.raises(ParamError, match=says):
        apply_overrides(CameraParams(), sets)
    ok = {"hfov_deg": 1e-30, "pixel_noise_std": 3e38, "image_width": 2**31 - 1}
    apply_overrides(CameraParams(), {k: ok[k] for k in sets})


def test_json_values_and_fingerprints():
    assert json_value(np.float32(0.5)) == 0.5 and type(json_value(np.float32(0.5))) is float
    assert json_value((1, np.int64(2))) == [1, 2] and json_value(np.arange(2)) == [0, 1]
    assert json_value(CameraParams) == repr(CameraParams)
    a = fingerprint({"x": 1, "y": [1.0, 2.0]})
    assert a == fingerprint({"y": (1.0, 2.0), "x": 1}) != fingerprint({"x": 2, "y": [1, 2]})
    assert len(a) == 16 and int(a, 16) >= 0


def test_traced_values_are_float32_int32_or_bool():
    assert traced_dtype(np.float64(1.0)) == np.float32 and traced_dtype(3) == np.int32
    assert traced_dtype(np.int64(3)) == np.int32 and traced_dtype(True) == np.bool_
    with pytest.raises(ParamError, match="static=True"):
        traced_dtype("abc")


def test_stacked_configs_repeat_each_point_for_its_seeds():
    cams = [CameraParams(hfov_deg=50.0), CameraParams(hfov_deg=60.0)]
    st = stack_traced(cams, repeats=3)
    np.testing.assert_array_equal(st.hfov_deg, [50.0] * 3 + [60.0] * 3)
    assert st.hfov_deg.dtype == np.float32 and st.image_width.dtype == np.int32
    assert dataclasses.is_dataclass(st)


def test_overrides_meet_the_whole_configs_rules_and_number_tuples_stay_numbers():
    with pytest.raises(ParamError, match="near_plane"):
        apply_overrides(CameraParams(), {"near_plane": 0.5})  # beyond the camera height
    from vbl.spaces.action_cells import CellMapParams

    with pytest.raises(ParamError, match="must be a tuple of numbers"):
        apply_overrides(CellMapParams(), {"bins": (4, True, 3, 3, 1)})
    assert apply_overrides(CellMapParams(), {"bins": (4, 2, 3, 3, 1)}).bins == (4, 2, 3, 3, 1)
