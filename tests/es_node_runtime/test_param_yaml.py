"""es_node_runtime.param_yaml: floats every ROS 2 reader reads as floats, and the trap read back."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import parameter_dict_from_yaml_file

from es_node_runtime.param_yaml import dump_parameters, floats_from_strings


def test_dotless_exponents_are_strings_to_pyyaml_which_is_the_trap() -> None:
    assert yaml.safe_load("a: [-4e-17, 1e-07]") == {"a": ["-4e-17", "1e-07"]}


def test_dumped_floats_load_as_floats_in_pyyaml_and_in_rclpy(tmp_path: Path) -> None:
    values = [-4e-17, 1e-07, 1e20, 1.5, 0.0, -0.0, 3.0]
    text = dump_parameters({"node": {"ros__parameters": {"law.m1": values, "v_limit": 1e-07}}})
    loaded = yaml.safe_load(text)["node"]["ros__parameters"]
    assert all(isinstance(v, float) for v in loaded["law.m1"])
    # equal, or (no dot in repr) one unit in the last place away
    for got, want in zip(loaded["law.m1"], values, strict=True):
        assert got == want or math.nextafter(want, 0.0) == got or math.nextafter(want, 1.0) == got
    assert loaded["law.m1"][3:7] == [1.5, 0.0, -0.0, 3.0]
    assert loaded["v_limit"] == pytest.approx(1e-07, rel=1e-15)
    # what `ros2 param load` reads the file with: str() of each value read again as YAML
    path = tmp_path / "p.yaml"
    path.write_text(text)
    parsed = parameter_dict_from_yaml_file(str(path))
    assert parsed["law.m1"].value.type == ParameterType.PARAMETER_DOUBLE_ARRAY
    assert parsed["v_limit"].value.type == ParameterType.PARAMETER_DOUBLE
    special = yaml.safe_load(dump_parameters({"x": [float("nan"), float("inf"), -float("inf")]}))
    assert math.isnan(special["x"][0]) and special["x"][1:] == [float("inf"), -float("inf")]


def test_the_trap_in_rclpy_with_a_plain_dump(tmp_path: Path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump({"node": {"ros__parameters": {"m1": [-4e-17]}}}))
    assert "-4.0e-17" in path.read_text()  # a dot in the file does not save it
    parsed = parameter_dict_from_yaml_file(str(path))
    assert parsed["m1"].value.type == ParameterType.PARAMETER_STRING_ARRAY


@given(st.floats(allow_nan=False, allow_infinity=False, allow_subnormal=False))
def test_every_finite_float_survives_within_one_ulp(value: float) -> None:
    loaded = yaml.safe_load(dump_parameters({"x": value}))["x"]
    assert isinstance(loaded, float)
    assert "." in repr(loaded) or "inf" in repr(loaded)
    assert loaded == value or abs(loaded - value) <= math.ulp(value)


def test_ints_strings_and_bools_keep_their_types() -> None:
    doc = {"n": {"ros__parameters": {"rows": 2, "mode": "observer", "on": True, "e": "1e5x"}}}
    assert yaml.safe_load(dump_parameters(doc)) == doc


def test_strings_that_are_floats_are_read_as_floats_and_named() -> None:
    tree = yaml.safe_load(
        "feedforward:\n  ros__parameters:\n    law:\n      m1: [-4e-17, 1.5e-17]\n"
        "    v_limit: 1e2\n    mode: observer\n    tag: '12'\n"
    )
    converted, names = floats_from_strings(tree)
    params = converted["feedforward"]["ros__parameters"]  # type: ignore[index]
    assert params["law"]["m1"] == [-4e-17, 1.5e-17]
    assert params["v_limit"] == 100.0 and isinstance(params["v_limit"], float)
    assert params["mode"] == "observer" and params["tag"] == "12"
    assert names == ["feedforward.ros__parameters.law.m1", "feedforward.ros__parameters.v_limit"]
