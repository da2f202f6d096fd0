"""GridWire: the bytes rclpy would send, and every message accepted or refused as one."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from es_msgs_py import grid_wire
from es_msgs_py.arrays import LayoutError, grid_to_msg, msg_to_grid
from es_msgs_py.grid_wire import GridWire

SHAPES = [(1, 1), (3, 5), (66, 66), (0, 4), (4, 0)]


@pytest.mark.parametrize("shape", SHAPES)
def test_encode_is_what_rclpy_serialises(shape: tuple[int, int]) -> None:
    wire = GridWire(shape)
    grid = np.random.default_rng(1).uniform(-1.0, 1.0, shape)
    raw = wire.encode(grid)
    decoded = deserialize_message(raw, Float64MultiArray)
    np.testing.assert_array_equal(msg_to_grid(decoded, shape), grid)
    expected = serialize_message(grid_to_msg(grid))
    assert len(raw) == len(expected)
    np.testing.assert_array_equal(wire.decode(expected), grid)  # rclpy's own bytes


def _no_rclpy(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Make rclpy's deserialiser count its calls and fail: the fast path must not need it."""
    calls: list[int] = []

    def refuse(raw: bytes, _type: object) -> None:
        calls.append(len(raw))
        raise RuntimeError("rclpy was asked")

    monkeypatch.setattr(grid_wire, "deserialize_message", refuse)
    return calls


@pytest.mark.parametrize("shape", SHAPES)
def test_decode_returns_an_aligned_copy_without_rclpy(
    shape: tuple[int, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    wire = GridWire(shape)
    calls = _no_rclpy(monkeypatch)
    grid = np.arange(shape[0] * shape[1], dtype=np.float64).reshape(shape) * 1e-9
    grid.flat[:1] = np.nan  # values are not the wire's business: the core validates them
    raw = wire.encode(grid)
    out = wire.decode(raw)
    np.testing.assert_array_equal(out, grid)
    assert out.flags.aligned and out.flags.c_contiguous and out.flags.writeable
    out[...] = 7.0  # its own memory, not the sample's or the encoder's
    np.testing.assert_array_equal(wire.decode(raw), grid)
    wire.encode(np.ones(shape))
    np.testing.assert_array_equal(wire.decode(raw), grid)
    assert calls == []


def test_encode_refuses_a_grid_of_another_shape() -> None:
    with pytest.raises(ValueError, match=r"grid is \(3, 4\), expected \(4, 3\)"):
        GridWire((4, 3)).encode(np.zeros((3, 4)))


def _with(msg: Float64MultiArray, **change: object) -> bytes:
    for name, value in change.items():
        if name == "data_offset":
            msg.layout.data_offset = value
        elif name == "dims":
            msg.layout.dim = value
        else:
            setattr(msg, name, value)
    return bytes(serialize_message(msg))


@pytest.mark.parametrize(
    ("raw", "match"),
    [
        (_with(grid_to_msg(np.zeros((3, 4)))), "grid is 3 x 4, expected 3 x 5"),
        (_with(grid_to_msg(np.zeros((3, 5))), data_offset=1), "data_offset must be 0"),
        (
            _with(grid_to_msg(np.zeros((3, 5))), dims=[
                MultiArrayDimension(label="col", size=3, stride=15),
                MultiArrayDimension(label="row", size=5, stride=5),
            ]),
            "labels must be",
        ),
        (_with(grid_to_msg(np.zeros((3, 5))), data=[0.0] * 14), "data has 14 elements"),
        (b"", "not a std_msgs/msg/Float64MultiArray"),
        (b"\x00\x01\x00\x00" + b"\xff" * 20, "not a std_msgs/msg/Float64MultiArray"),
    ],
)
def test_decode_refuses_what_msg_to_grid_refuses(raw: bytes, match: str) -> None:
    with pytest.raises(LayoutError, match=match):
        GridWire((3, 5)).decode(raw)


def test_decode_takes_a_contract_message_whatever_its_padding_bytes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    wire = GridWire((3, 5))
    calls = _no_rclpy(monkeypatch)
    grid = np.random.default_rng(2).uniform(size=(3, 5))
    raw = bytearray(wire.encode(grid))
    data_start = len(raw) - 8 * 15
    raw[data_start - 4:data_start] = b"\xab\xcd\xef\x01"  # CDR leaves padding undefined
    np.testing.assert_array_equal(wire.decode(bytes(raw)), grid)
    assert calls == []


def test_decode_falls_back_to_rclpy_for_another_encapsulation(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    wire = GridWire((2, 2))
    grid = np.array([[1.0, 2.0], [3.0, 4.0]])
    raw = bytearray(wire.encode(grid))
    raw[3] = 1  # encapsulation options: not the head the fast path knows
    np.testing.assert_array_equal(wire.decode(bytes(raw)), grid)
    calls = _no_rclpy(monkeypatch)
    with pytest.raises(LayoutError, match="rclpy was asked"):
        wire.decode(bytes(raw))
    assert calls == [len(raw)]
