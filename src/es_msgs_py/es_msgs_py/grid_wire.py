"""Grids <-> the CDR bytes of their contract messages, without rclpy message objects.

A node that takes its busiest input raw (``create_subscription(..., raw=True)``) and
publishes bytes skips rclpy's per-message Python objects (a ``Float64MultiArray``, its
layout and two dimensions, each built and type-checked in Python): at 66 x 66 and 2 kHz the
feedforward node's CPU per set point fell from 0.39-0.42 to 0.34-0.37 ms with it. The bytes
are the ones rclpy would send; ``ros2 topic echo``, bags and every other reader see the same
messages.

Every contract grid of one shape serialises to the same head (encapsulation, both
dimensions, ``data_offset`` 0, the element count) followed by alignment padding and the
values. :meth:`GridWire.decode` reads the values straight from bytes that start with that
head; anything else (another layout, another serialiser's encapsulation options, a corrupt
sample) goes through rclpy's deserialiser and :func:`es_msgs_py.arrays.msg_to_grid`, so it
is accepted or refused exactly as a message would be, with the same error.
"""

from __future__ import annotations

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float64MultiArray

from es_msgs_py.arrays import COL_LABEL, ROW_LABEL, FloatArray, grid_to_msg, msg_to_grid
from es_msgs_py.errors import LayoutError

#: Bytes of the CDR encapsulation header that precedes the payload.
ENCAPSULATION_BYTES = 4
_ITEM = np.dtype(np.float64).itemsize


def _aligned(offset: int, alignment: int) -> int:
    return -(-offset // alignment) * alignment


def _count_end(labels: tuple[str, ...]) -> int:
    """Payload offset [bytes] just past the element count of a message with these dimensions."""
    offset = 4  # number of dimensions
    for label in labels:
        offset += 4 + len(label.encode()) + 1  # string: length, characters, NUL
        offset = _aligned(offset, 4) + 8  # size, stride
    return offset + 8  # data_offset, element count


class GridWire:
    """Encoder and decoder of one grid shape's contract messages as CDR bytes.

    Args:
        shape: the (R, C) grid every message carries.

    Raises:
        RuntimeError: rclpy's serialiser lays the contract message out differently than the
            CDR rules this class relies on (not expected; checked once here).

    """

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = (int(shape[0]), int(shape[1]))
        template = serialize_message(grid_to_msg(np.zeros(self.shape)))
        head_end = ENCAPSULATION_BYTES + _count_end((ROW_LABEL, COL_LABEL))
        self._data_start = ENCAPSULATION_BYTES + _aligned(head_end - ENCAPSULATION_BYTES, _ITEM)
        self._size = self.shape[0] * self.shape[1]
        self._length = self._data_start + _ITEM * self._size
        if len(template) != self._length:
            raise RuntimeError(
                f"contract grid {self.shape} serialises to {len(template)} bytes, "
                f"expected {self._length}"
            )
        self._head = template[:head_end]  # the padding after it is not defined by CDR
        self._prefix = bytes(template[: self._data_start])  # head and padding, as rclpy's

    def decode(self, raw: bytes) -> FloatArray:
        """Return the grid of one serialised message as a new float64 array.

        Raises:
            LayoutError: the message's layout does not match the contract or the shape (the
                message of :func:`es_msgs_py.arrays.msg_to_grid`), or the bytes are not a
                ``Float64MultiArray`` at all.

        """
        if len(raw) == self._length and raw.startswith(self._head):
            values = np.frombuffer(raw, np.float64, count=self._size, offset=self._data_start)
            return values.reshape(self.shape).copy()  # aligned, and not tied to the sample
        try:
            msg = deserialize_message(raw, Float64MultiArray)
        except RuntimeError as err:  # rclpy's RMWError: not a Float64MultiArray
            raise LayoutError(
                f"not a std_msgs/msg/Float64MultiArray ({len(raw)} bytes): {err}"
            ) from err
        return msg_to_grid(msg, self.shape)

    def encode(self, grid: FloatArray) -> bytes:
        """Return the serialised contract message of ``grid`` (the class's shape).

        Raises:
            ValueError: ``grid`` is not of the class's shape.

        """
        values = np.ascontiguousarray(grid, np.float64)
        if values.shape != self.shape:
            raise ValueError(f"grid is {values.shape}, expected {self.shape}")
        # the values go from the array's buffer into the new bytes: one copy
        return b"".join((self._prefix, values.data))
