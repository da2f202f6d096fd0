"""The array type aliases: one dtype each, free of ROS, and written nowhere else."""

from __future__ import annotations

import re
import subprocess
import sys
import typing

import numpy as np
import pytest
from support.workspace import ROOT, modules, packages

from es_common import arrays

#: A numpy array type of one of the shared dtypes, spelt out (``npt.NDArray[np.float64]``).
SPELT_OUT = re.compile(r"npt\.NDArray\[np\.(float64|bool_|intp|int64)\]")


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


def test_no_package_spells_out_a_shared_alias() -> None:
    """Product code imports the aliases from es_common.arrays (testing/standgen stays independent
    of product code and has its own, standgen._typing)."""
    again = [
        f"{path.relative_to(ROOT)}:{line}"
        for package in packages()
        if package != "es_common"
        for path in modules(package)
        for line, text in enumerate(path.read_text().splitlines(), 1)
        if SPELT_OUT.search(text)
    ]
    assert not again, "use es_common.arrays instead:\n" + "\n".join(again)
