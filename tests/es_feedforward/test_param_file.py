"""ROS 2 parameters YAML: write, read back, per-actuator maps, readable errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from rclpy.parameter import Parameter, parameter_dict_from_yaml_file

from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import FeedforwardConfig, Mode
from es_feedforward.param_file import (
    config_from_parameters,
    config_to_parameters,
    read_params_file,
    write_params_file,
)
from es_physics.params import ActuatorParams

from .plantlike import grid_params

SHAPE = (3, 4)
HEAD = "feedforward:\n  ros__parameters: {rows: 2, cols: 2, "


def config() -> FeedforwardConfig:
    return FeedforwardConfig(
        shape=SHAPE,
        params=grid_params(SHAPE),
        mode=Mode.OBSERVER,
        v_limit=300.0,
        compensation=CompensationParams(delay_s=0.0024, coupling=0.02),
    )


def assert_same(a: FeedforwardConfig, b: FeedforwardConfig) -> None:
    assert config_to_parameters(a) == config_to_parameters(b)


def test_round_trip_with_per_actuator_maps(tmp_path: Path) -> None:
    path = tmp_path / "ff.yaml"
    original = config()
    write_params_file(path, original)
    loaded = read_params_file(path)
    assert_same(loaded, original)
    np.testing.assert_array_equal(loaded.params.m2, original.params.m2)
    # rclpy reads the same file as double arrays (what --params-file gives the node)
    parsed = {
        name: Parameter.from_parameter_msg(msg)
        for name, msg in parameter_dict_from_yaml_file(str(path)).items()
    }
    assert parsed["law.m2"].type_ is Parameter.Type.DOUBLE_ARRAY
    assert list(parsed["law.m2"].value) == np.ravel(original.params.m2).tolist()
    assert parsed["law.L"].type_ is Parameter.Type.DOUBLE_ARRAY
    assert parsed["compensation.delay_s"].value == 0.0024
    assert parsed["rows"].value == 3


def test_values_without_a_dot_are_written_so_every_reader_gets_floats(tmp_path: Path) -> None:
    path = tmp_path / "ff.yaml"
    original = FeedforwardConfig(
        shape=(1, 2),
        params=replace(ActuatorParams(), m1=-4e-17, m3=1e-07, k3=np.array([[1e-20, 2e-20]])),
    )
    write_params_file(path, original)
    values = yaml.safe_load(path.read_text())["feedforward"]["ros__parameters"]  # PyYAML
    assert all(isinstance(values[f"law.{name}"][0], float) for name in ("m1", "m3", "k3"))
    assert values["law.m1"][0] == pytest.approx(-4e-17, rel=1e-15)  # within one ulp
    parsed = parameter_dict_from_yaml_file(str(path))  # rclpy, as `ros2 param load` reads it
    for name in ("m1", "m3", "k3"):
        assert Parameter.from_parameter_msg(parsed[f"law.{name}"]).type_ is (
            Parameter.Type.DOUBLE_ARRAY
        )
    np.testing.assert_allclose(read_params_file(path).params.k3, [[1e-20, 2e-20]], rtol=1e-15)


def test_strings_that_are_floats_are_read_as_floats(tmp_path: Path) -> None:
    path = tmp_path / "dumped.yaml"  # what `ros2 param dump` writes for such values
    path.write_text(
        "/feedforward:\n  ros__parameters:\n    rows: 1\n    cols: 1\n"
        "    law:\n      m1:\n      - -4e-17\n    v_limit: 3e2\n"
    )
    loaded = read_params_file(path)
    assert loaded.params.m1 == -4e-17
    assert loaded.v_limit == 300.0


def test_nested_names_and_wildcard_node(tmp_path: Path) -> None:
    path = tmp_path / "nested.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "/**": {"ros__parameters": {"rows": 2, "cols": 2, "law": {"k2": [1.2e-6]}}},
                "feedforward": {
                    "ros__parameters": {"law": {"m2": [1.5e-15, 1.6e-15, 1.4e-15, 1.5e-15]}}
                },
            }
        )
    )
    loaded = read_params_file(path)
    assert loaded.shape == (2, 2)
    assert loaded.params.k2 == 1.2e-6
    assert np.asarray(loaded.params.m2).tolist() == [[1.5e-15, 1.6e-15], [1.4e-15, 1.5e-15]]


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("feedforward: [1, 2", "cannot read"),
        ("- 1\n- 2\n", "not a ROS 2 parameters file"),
        ("other_node:\n  ros__parameters: {rows: 2, cols: 2}\n", "no ros__parameters"),
        ("feedforward:\n  ros__parameters: {rows: 2}\n", "rows and cols"),
        (
            "feedforward:\n  ros__parameters: {rows: 2, cols: 2, 'law.m2': [1.0, 2.0, 3.0]}\n",
            "law.m2",
        ),
        (f"{HEAD}mode: fast}}\n", "mode"),
        (
            "feedforward:\n  ros__parameters: {rows: 2, cols: 2, 'compensation.delay_s': 5.0}\n",
            "delay_s",
        ),
        (
            "feedforward:\n  ros__parameters: {rows: 2, cols: 2, 'law.k2': [-1.0e-6]}\n",
            "not positive",
        ),
    ],
)
def test_bad_files_give_one_readable_line(tmp_path: Path, content: str, match: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(content)
    with pytest.raises(ValueError, match=match) as info:
        read_params_file(path)
    assert "\n" not in str(info.value)


def test_missing_file_is_a_readable_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="cannot read"):
        read_params_file(tmp_path / "absent.yaml")


def test_partial_update_keeps_the_rest() -> None:
    base = config()
    updated = config_from_parameters({"mode": "inverse_quadratic", "law.k1": [-18e-9]}, base)
    assert updated.mode is Mode.INVERSE_QUADRATIC
    assert updated.params.k1 == -18e-9
    np.testing.assert_array_equal(updated.params.m2, base.params.m2)
    assert updated.compensation == base.compensation
