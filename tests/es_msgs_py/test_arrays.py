from __future__ import annotations

import numpy as np
import pytest
from std_msgs.msg import MultiArrayDimension

from es_msgs_py.arrays import (
    LayoutError,
    grid_to_msg,
    msg_to_grid,
    msg_to_sensors,
    sensors_to_msg,
)


def test_grid_round_trip_keeps_values_and_layout() -> None:
    grid = np.arange(12.0).reshape(3, 4) * 1e-9
    msg = grid_to_msg(grid)
    assert [(d.label, d.size, d.stride) for d in msg.layout.dim] == [("row", 3, 12), ("col", 4, 4)]
    assert msg.layout.data_offset == 0
    np.testing.assert_array_equal(msg_to_grid(msg, (3, 4)), grid)


def test_sensor_round_trip() -> None:
    values = np.array([40.0, np.nan, 41.5])
    msg = sensors_to_msg(values)
    assert [(d.label, d.size, d.stride) for d in msg.layout.dim] == [("sensor", 3, 3)]
    np.testing.assert_array_equal(msg_to_sensors(msg, 3), values)


def test_result_does_not_alias_message() -> None:
    msg = grid_to_msg(np.zeros((2, 2)))
    out = msg_to_grid(msg)
    out[0, 0] = 1.0
    assert msg.data[0] == 0.0


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda m: setattr(m.layout.dim[0], "label", "x"), "labels"),
        (lambda m: setattr(m.layout.dim[1], "stride", 5), "strides"),
        (lambda m: setattr(m.layout, "data_offset", 1), "data_offset"),
        (lambda m: m.data.pop(), "elements"),
        (lambda m: setattr(m.layout, "dim", m.layout.dim[:1]), "2 dims"),
    ],
)
def test_grid_layout_errors(mutate, match: str) -> None:
    msg = grid_to_msg(np.zeros((2, 3)))
    mutate(msg)
    with pytest.raises(LayoutError, match=match):
        msg_to_grid(msg)


def test_grid_shape_mismatch() -> None:
    with pytest.raises(LayoutError, match="expected 3 x 2"):
        msg_to_grid(grid_to_msg(np.zeros((2, 3))), (3, 2))


def test_sensor_layout_errors() -> None:
    msg = sensors_to_msg(np.zeros(4))
    with pytest.raises(LayoutError, match="expected 5"):
        msg_to_sensors(msg, 5)
    msg.layout.dim.append(MultiArrayDimension(label="x", size=1, stride=1))
    with pytest.raises(LayoutError, match="1 dim"):
        msg_to_sensors(msg)
    with pytest.raises(LayoutError, match="1-D"):
        sensors_to_msg(np.zeros((2, 2)))
