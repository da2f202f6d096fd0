"""Grid and sensor arrays <-> ``std_msgs/msg/Float64MultiArray`` with the contract's layout.

Grid (per actuator): row-major R x C, ``layout.dim = [row(size R, stride R*C),
col(size C, stride C)]``. Sensors: ``layout.dim = [sensor(size S, stride S)]``. Both with
``data_offset == 0`` and ``len(data) == R*C`` (or S).

Conversion copies the buffer once (``array.array.frombytes`` / ``np.frombuffer``), or not at
all for a read-only view (``msg_to_grid(..., copy=False)``); there is no per-element Python
work, so a 4096-element grid costs a few microseconds.
"""

from __future__ import annotations

import array

import numpy as np
import numpy.typing as npt
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from es_common.arrays import FloatArray
from es_msgs_py.errors import LayoutError

ROW_LABEL = "row"
COL_LABEL = "col"
SENSOR_LABEL = "sensor"

def _buffer_of(
    values: npt.ArrayLike, expected_ndim: int, what: str
) -> tuple[FloatArray, array.array]:
    arr = np.ascontiguousarray(values, dtype=np.float64)
    if arr.ndim != expected_ndim:
        raise LayoutError(f"{what} must be {expected_ndim}-D, got shape {arr.shape}")
    buf = array.array("d")
    if arr.size:  # a memoryview of an empty array cannot be cast (0 x C grids stay empty)
        buf.frombytes(arr.data.cast("B"))
    return arr, buf


def grid_to_msg(grid: npt.ArrayLike) -> Float64MultiArray:
    """Return a ``Float64MultiArray`` holding an R x C grid in the contract's layout."""
    arr, buf = _buffer_of(grid, 2, "grid")
    rows, cols = arr.shape
    msg = Float64MultiArray()
    msg.layout.dim = [
        MultiArrayDimension(label=ROW_LABEL, size=rows, stride=rows * cols),
        MultiArrayDimension(label=COL_LABEL, size=cols, stride=cols),
    ]
    msg.layout.data_offset = 0
    msg.data = buf
    return msg


def sensors_to_msg(values: npt.ArrayLike) -> Float64MultiArray:
    """Return a ``Float64MultiArray`` holding S sensor values in the contract's layout."""
    arr, buf = _buffer_of(values, 1, "sensor vector")
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=SENSOR_LABEL, size=arr.size, stride=arr.size)]
    msg.layout.data_offset = 0
    msg.data = buf
    return msg


def _data_view(msg: Float64MultiArray, expected_len: int) -> FloatArray:
    if msg.layout.data_offset != 0:
        raise LayoutError(f"data_offset must be 0, got {msg.layout.data_offset}")
    data = np.frombuffer(msg.data, dtype=np.float64)
    if data.size != expected_len:
        raise LayoutError(f"data has {data.size} elements, layout says {expected_len}")
    return data


def msg_to_grid(
    msg: Float64MultiArray, shape: tuple[int, int] | None = None, *, copy: bool = True
) -> FloatArray:
    """Return the R x C grid of a contract message as a new float64 array.

    Args:
        msg: the message to read.
        shape: the (R, C) the receiver is configured for; ``None`` accepts any grid.
        copy: ``False`` returns a read-only view of the message's buffer instead (no copy;
            it keeps the message's data alive). For a receiver that owns the message (rclpy
            builds a new one per received sample) and never writes to the grid.

    Raises:
        LayoutError: labels, sizes, strides, offset or length do not match the contract or
            ``shape``. Values are not checked here (NaN passes); callers validate them.

    """
    dims = msg.layout.dim
    if len(dims) != 2:
        labels = [d.label for d in dims]
        raise LayoutError(f"grid layout needs 2 dims (row, col), got {len(dims)} {labels}")
    row, col = dims
    if row.label != ROW_LABEL or col.label != COL_LABEL:
        raise LayoutError(
            f"grid dim labels must be ('row', 'col'), got ({row.label!r}, {col.label!r})"
        )
    rows, cols = int(row.size), int(col.size)
    if row.stride != rows * cols or col.stride != cols:
        raise LayoutError(
            f"grid strides must be ({rows * cols}, {cols}) for {rows} x {cols}, "
            f"got ({row.stride}, {col.stride})"
        )
    if shape is not None and (rows, cols) != tuple(shape):
        raise LayoutError(f"grid is {rows} x {cols}, expected {shape[0]} x {shape[1]}")
    grid = _data_view(msg, rows * cols).reshape(rows, cols)
    if copy:
        return grid.copy()
    grid.flags.writeable = False
    return grid


def msg_to_sensors(msg: Float64MultiArray, count: int | None = None) -> FloatArray:
    """Return the S sensor values of a contract message as a new float64 vector.

    Args:
        msg: the message to read.
        count: the number of sensors the receiver is configured for; ``None`` accepts any.

    Raises:
        LayoutError: label, size, stride, offset or length do not match the contract or
            ``count``.

    """
    dims = msg.layout.dim
    if len(dims) != 1:
        labels = [d.label for d in dims]
        raise LayoutError(f"sensor layout needs 1 dim ('sensor'), got {len(dims)} {labels}")
    (dim,) = dims
    if dim.label != SENSOR_LABEL:
        raise LayoutError(f"sensor dim label must be 'sensor', got {dim.label!r}")
    size = int(dim.size)
    if dim.stride != size:
        raise LayoutError(f"sensor stride must be {size}, got {dim.stride}")
    if count is not None and size != count:
        raise LayoutError(f"message has {size} sensors, expected {count}")
    return _data_view(msg, size).copy()
