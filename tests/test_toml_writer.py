"""The one TOML writer (``recon.params.dumps_toml``, tomli_w): numpy values, headers, None and bad values."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from recon.paper import PaperParams
from recon.params import dumps_toml, params_from_dict, params_to_dict

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def test_numpy_scalars_and_arrays_round_trip_as_python_values():
    data = {
        "f": np.float64(0.1), "f32": np.float32(0.5), "i": np.int64(-7), "u": np.uint8(200), "b": np.bool_(True),
        "s": np.str_("side"), "v": np.array([1.5, -0.25, 1e-17]), "ints": np.arange(3), "bools": np.array([True, False]),
        "m": np.eye(2), "t": (np.float64(2.0), 3), "table": {"k": np.int32(4), "deep": {"x": np.float64(np.pi)}},
    }
    back = tomllib.loads(dumps_toml(data))
    assert back == {
        "f": 0.1, "f32": 0.5, "i": -7, "u": 200, "b": True, "s": "side", "v": [1.5, -0.25, 1e-17], "ints": [0, 1, 2],
        "bools": [True, False], "m": [[1.0, 0.0], [0.0, 1.0]], "t": [2.0, 3], "table": {"k": 4, "deep": {"x": np.pi}},
    }
    assert type(back["i"]) is int and type(back["b"]) is bool and type(back["f"]) is float


def test_non_finite_floats_are_toml_literals():
    back = tomllib.loads(dumps_toml({"a": np.float64("nan"), "b": [np.inf, -np.inf]}))
    assert np.isnan(back["a"]) and back["b"] == [np.inf, -np.inf]


def test_header_becomes_comment_lines_before_the_document():
    text = dumps_toml({"method": "paper", "x": 1}, header="first\n\nthird")
    assert text.startswith("# first\n#\n# third\n\nmethod = \"paper\"\n")
    assert tomllib.loads(text) == {"method": "paper", "x": 1}
    assert not dumps_toml({"x": 1}).startswith("#")


def test_none_values_are_left_out_and_parameters_round_trip():
    assert tomllib.loads(dumps_toml({"a": None, "t": {"b": None, "c": 1}})) == {"t": {"c": 1}}
    params = PaperParams()
    back = params_from_dict(PaperParams, tomllib.loads(dumps_toml(params_to_dict(params))))
    assert back == params


@pytest.mark.parametrize("data, where", [
    ({"t": {"x": [1.0, None]}}, "t.x[1]"),
    ({"obj": object()}, "obj"),
    ({"t": {1: 2.0}}, "t.1"),
])
def test_values_toml_cannot_hold_are_one_line_errors_naming_the_key(data, where):
    with pytest.raises(TypeError) as err:
        dumps_toml(data)
    msg = str(err.value)
    assert msg.startswith(f"{where}: ") and "\n" not in msg


def test_the_document_must_be_a_table():
    with pytest.raises(TypeError, match="TOML document: must be a dict"):
        dumps_toml([1, 2])
