"""CDR encoding and decoding of the contract's ``Float64MultiArray`` with numpy (no rclpy).

Grids are (R, C) with ``layout.dim = [row(R, R*C), col(C, C)]``, sensor vectors (S,) with
``[sensor(S, S)]``, both with ``data_offset == 0`` (``shared/docs/interfaces.md``). Decoding
checks the CDR headers of many payloads in blocks with one numpy comparison and copies each
payload's values with one memcpy: no per-element Python work.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from es_common.arrays import FloatArray
from es_msgs_py.bag.errors import BagLayoutError, CorruptBagError, UnsupportedBagError

__all__ = [
    "COL_LABEL",
    "FLOAT64_MULTI_ARRAY",
    "ROW_LABEL",
    "SENSOR_LABEL",
    "FloatArray",
    "decode_float64_multi_arrays",
    "encode_float64_multi_array",
]

FLOAT64_MULTI_ARRAY: Final = "std_msgs/msg/Float64MultiArray"

# The contract's labels, as in es_msgs_py.arrays (not imported: it needs the ROS message
# classes, and bag I/O must work with numpy and rosbags alone).
ROW_LABEL: Final = "row"
COL_LABEL: Final = "col"
SENSOR_LABEL: Final = "sensor"

_CDR_LE: Final = b"\x00\x01\x00\x00"
_CDR_BE: Final = b"\x00\x00\x00\x00"
# Messages whose headers are compared in one numpy operation.
_BLOCK_MESSAGES: Final = 4096


def _align(offset: int, size: int) -> int:
    return offset + (-offset % size)


def encode_float64_multi_array(values: npt.ArrayLike, kind: Literal["grid", "sensor"]) -> bytes:
    """Return the CDR payload of a contract ``Float64MultiArray`` holding ``values``.

    ``kind="grid"`` takes an (R, C) array, ``kind="sensor"`` an (S,) vector. The bytes equal
    rclpy's ``serialize_message`` of the same message except for the CDR padding, which is
    zero here and undefined there.

    Raises:
        BagLayoutError: ``values`` is not 2-D (grid) or 1-D (sensor).

    """
    arr = np.ascontiguousarray(values, dtype="<f8")
    if kind == "grid":
        if arr.ndim != 2:
            raise BagLayoutError(f"a grid must be 2-D, got shape {arr.shape}")
        rows, cols = arr.shape
        dims = [(ROW_LABEL, rows, rows * cols), (COL_LABEL, cols, cols)]
    else:
        if arr.ndim != 1:
            raise BagLayoutError(f"a sensor vector must be 1-D, got shape {arr.shape}")
        dims = [(SENSOR_LABEL, arr.size, arr.size)]
    return _layout_header(dims, arr.size) + arr.tobytes()


def _layout_header(dims: Sequence[tuple[str, int, int]], count: int) -> bytes:
    body = bytearray(struct.pack("<I", len(dims)))
    for label, size, stride in dims:
        raw = label.encode() + b"\x00"
        body += struct.pack("<I", len(raw)) + raw
        body += bytes(_align(len(body), 4) - len(body))
        body += struct.pack("<II", size, stride)
    body += struct.pack("<II", 0, count)  # data_offset, sequence length
    if count:
        body += bytes(_align(len(body), 8) - len(body))
    return _CDR_LE + bytes(body)


@dataclass(frozen=True)
class _ArrayHeader:
    """The parsed layout of one Float64MultiArray payload."""

    dims: tuple[tuple[str, int, int], ...]
    data_offset: int
    count: int
    data_start: int
    dtype: str
    #: Offsets of the header bytes that carry information (CDR padding is left out: rclpy
    #: does not clear it, so it differs between otherwise identical messages).
    significant: tuple[int, ...]

    def shape(self, topic: str) -> tuple[int, ...]:
        """Return the array shape the layout describes (R, C) or (S,).

        Raises:
            BagLayoutError: the layout is not the contract's grid or sensor layout.

        """
        labels = tuple(label for label, _, _ in self.dims)
        sizes = tuple(size for _, size, _ in self.dims)
        strides = tuple(stride for _, _, stride in self.dims)
        if labels == (ROW_LABEL, COL_LABEL):
            rows, cols = sizes
            if strides != (rows * cols, cols):
                raise BagLayoutError(
                    f"{topic}: grid strides {strides} do not match {rows} x {cols}"
                )
        elif labels == (SENSOR_LABEL,):
            if strides != sizes:
                raise BagLayoutError(f"{topic}: sensor stride {strides[0]} != size {sizes[0]}")
        else:
            raise BagLayoutError(
                f"{topic}: layout labels {list(labels)} are neither ['row', 'col'] nor ['sensor']"
            )
        if self.data_offset != 0:
            raise BagLayoutError(
                f"{topic}: data_offset is {self.data_offset}, the contract needs 0"
            )
        if self.count != int(np.prod(sizes)):
            raise BagLayoutError(f"{topic}: {self.count} values for a layout of shape {sizes}")
        return sizes


def _parse_array_header(payload: memoryview, topic: str) -> _ArrayHeader:
    """Parse the CDR layout of a Float64MultiArray payload (not its values).

    Raises:
        UnsupportedBagError: the CDR encapsulation is not plain little/big-endian CDR.
        CorruptBagError: the payload is cut or its length does not match its header.

    """
    try:
        if bytes(payload[:4]) not in (_CDR_LE, _CDR_BE):
            raise UnsupportedBagError(
                f"{topic}: unsupported CDR encapsulation {bytes(payload[:4]).hex()}"
            )
        order = "<" if bytes(payload[:4]) == _CDR_LE else ">"
        body = payload[4:]
        pos = 0
        significant = list(range(4))

        def uint32() -> int:
            nonlocal pos
            pos = _align(pos, 4)
            (value,) = struct.unpack_from(order + "I", body, pos)
            significant.extend(range(4 + pos, 8 + pos))
            pos += 4
            return int(value)

        dims = []
        for _ in range(uint32()):
            length = uint32()
            label = bytes(body[pos : pos + length]).rstrip(b"\x00").decode()
            significant.extend(range(4 + pos, 4 + pos + length))
            pos += length
            dims.append((label, uint32(), uint32()))
        data_offset = uint32()
        count = uint32()
        if count:
            pos = _align(pos, 8)
    except (struct.error, UnicodeDecodeError):
        raise CorruptBagError(f"{topic}: truncated or corrupt Float64MultiArray payload") from None
    if 4 + pos + 8 * count != len(payload):
        raise CorruptBagError(
            f"{topic}: payload of {len(payload)} bytes does not hold {count} values"
        )
    return _ArrayHeader(tuple(dims), data_offset, count, 4 + pos, order + "f8", tuple(significant))


def decode_float64_multi_arrays(topic: str, payloads: Sequence[memoryview | bytes]) -> FloatArray:
    """Decode contract ``Float64MultiArray`` payloads into one (N, R, C) or (N, S) array.

    Payloads sharing the first one's layout (the normal case) are checked in blocks with one
    vectorised comparison of their headers, then copied straight into the result (one
    memcpy per message, no intermediate buffer: bags of a few GB stay within memory).

    Args:
        topic: the topic name, for messages.
        payloads: N CDR payloads; none gives an empty (0, 0) array.

    Raises:
        BagLayoutError: a layout is not the contract's, or shapes differ within the topic.
        CorruptBagError: a payload is cut or inconsistent with its header.
        UnsupportedBagError: a payload is not plain CDR.

    """
    if not payloads:
        return np.empty((0, 0))
    first = _parse_array_header(memoryview(payloads[0]), topic)
    shape = first.shape(topic)
    out = np.empty((len(payloads), first.count), dtype=np.float64)
    size = first.data_start + 8 * first.count
    significant = np.array(first.significant, dtype=np.intp)
    header = np.frombuffer(bytes(payloads[0]), dtype=np.uint8)[significant]
    data_start, dtype, count = first.data_start, first.dtype, first.count
    for start in range(0, len(payloads), _BLOCK_MESSAGES):
        block = payloads[start : start + _BLOCK_MESSAGES]
        if all(len(p) == size for p in block):
            heads = np.frombuffer(b"".join([p[:data_start] for p in block]), dtype=np.uint8)
            if (heads.reshape(len(block), data_start)[:, significant] == header).all():
                for i, payload in enumerate(block, start):
                    out[i] = np.frombuffer(payload, dtype, count, data_start)
                continue
        for i, payload in enumerate(block, start):
            this = _parse_array_header(memoryview(payload), topic)
            if this.shape(topic) != shape:
                raise BagLayoutError(
                    f"{topic}: inconsistent array shapes in one topic: {shape} at message 0, "
                    f"{this.shape(topic)} at message {i}"
                )
            out[i] = np.frombuffer(payload, this.dtype, this.count, this.data_start)
    return out.reshape(len(payloads), *shape)
