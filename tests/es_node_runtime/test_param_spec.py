"""es_node_runtime.param_spec: what a parameter accepts, and typed read-back of declared values."""

from __future__ import annotations

import array

import numpy as np
import pytest

from es_node_runtime.errors import ParameterTypeError
from es_node_runtime.param_spec import ParameterSpec, ParameterValues

VALUES = ParameterValues(
    {
        "rate": 10.0,
        "count": 3,
        "whole": 4.0,
        "flag": True,
        "name": "model",
        "array": array.array("d", [1.0, 2.5]),
        "ints": [1, 2],
        "untyped_empty": b"",
        "names": ["thermal", "feedforward"],
        "numpy": np.float64(2.5),
    }
)


def test_typed_getters_return_the_values_with_their_types() -> None:
    assert VALUES.get_float("rate") == 10.0
    assert VALUES.get_float("count") == 3.0 and isinstance(VALUES.get_float("count"), float)
    assert VALUES.get_float("numpy") == 2.5
    assert VALUES.get_int("count") == 3 and VALUES.get_int("whole") == 4
    assert VALUES.get_bool("flag") is True
    assert VALUES.get_str("name") == "model"
    assert VALUES.get_floats("array") == [1.0, 2.5] and VALUES.get_floats("ints") == [1.0, 2.0]
    assert VALUES.get_floats("untyped_empty") == [] and VALUES.get_strs("untyped_empty") == []
    assert VALUES.get_strs("names") == ["thermal", "feedforward"]


def test_defaults_stand_in_for_absent_names_only() -> None:
    assert VALUES.get_float("absent", 1.5) == 1.5
    assert VALUES.get_float("rate", 1.5) == 10.0
    assert VALUES.get_int("absent", 7) == 7 and VALUES.get_str("absent", "x") == "x"
    with pytest.raises(KeyError):
        VALUES.get_float("absent")


@pytest.mark.parametrize(
    ("getter", "name"),
    [
        ("get_float", "flag"),  # a bool is no number
        ("get_float", "name"),
        ("get_float", "array"),
        ("get_int", "rate_frac"),
        ("get_int", "flag"),
        ("get_bool", "count"),
        ("get_str", "rate"),
        ("get_floats", "name"),
        ("get_floats", "names"),
        ("get_strs", "ints"),
    ],
)
def test_a_value_of_the_wrong_type_raises_a_type_error_naming_it(getter: str, name: str) -> None:
    values = ParameterValues({**VALUES, "rate_frac": 2.5})
    with pytest.raises(ParameterTypeError, match=f"parameter {name}=") as err:
        getattr(values, getter)(name)
    assert isinstance(err.value, TypeError) and isinstance(err.value, ValueError)


def test_values_are_a_read_only_mapping_of_the_raw_values() -> None:
    assert VALUES["count"] == 3 and "rate" in VALUES and len(VALUES) == 10
    assert dict(ParameterValues({"a": 1})) == {"a": 1}


def test_a_spec_rejects_out_of_range_values_choices_and_failed_checks() -> None:
    spec = ParameterSpec("x", 1.0, "A rate, Hz.", low=0.0, high=2.0)
    assert spec.reason_to_reject(1.5) is None and spec.reason_to_reject(True) is None
    assert spec.reason_to_reject(2.5) == "x=2.5 is outside [0.0, 2.0]"
    choice = ParameterSpec("mode", "a", "Mode.", choices=("a", "b"))
    assert choice.reason_to_reject("c") == "mode='c' is not one of ['a', 'b']"
    assert choice.full_description() == "Mode. One of: a, b."
    checked = ParameterSpec("even", 2, "Even.", check=lambda v: None if v == 2 else "odd")
    assert checked.reason_to_reject(3) == "odd"
