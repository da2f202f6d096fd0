"""The array type aliases: one dtype each, and free of ROS."""

from __future__ import annotations

import subprocess
import sys
import typing

import numpy as np
import pytest

from es_common import arrays


@pytest.mark.parametrize(
    ("alias", "dtype"),
    [
        (arrays.FloatArray, np.float64),
        (arrays.BoolArray, np.bool_),
        (arrays.IndexArray, np.intp),
        (arrays.IntArray, np.int64),
    ],
)
def test_each_alias_is_an_ndarray_of_its_dtype(alias: object, dtype: type) -> None:
    assert typing.get_origin(alias) is np.ndarray
    (scalar,) = typing.get_args(typing.get_args(alias)[1])
    assert scalar is dtype


def test_importing_es_common_loads_no_ros() -> None:
    code = "import sys, es_common.arrays, es_common.lazy; print('rclpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
