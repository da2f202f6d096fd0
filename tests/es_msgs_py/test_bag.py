"""Bag I/O: round trips in both storages, contract decoding, and every failure mode."""

from __future__ import annotations

import os
import shutil
import signal
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import ConnectionExtRosbag2
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray, String

from es_msgs_py.arrays import grid_to_msg, msg_to_grid, msg_to_sensors, sensors_to_msg
from es_msgs_py.bag import (
    FLOAT64_MULTI_ARRAY,
    BagError,
    BagWriter,
    decode_float64_multi_arrays,
    encode_float64_multi_array,
    read_bag,
    write_array_bag,
)
from es_msgs_py.diagnostics import Level, make_array, make_status
from es_msgs_py.topics import CLOCK, COMMAND, DIAGNOSTICS, DM_DEPTH, TEMPERATURE_RAW

STORAGES = ["mcap", "sqlite3"]
RNG = np.random.default_rng(7)
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def _storage_file(bag: Path) -> Path:
    (file,) = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    return file


def _small_bag(path: Path, storage: str = "mcap", n: int = 20) -> np.ndarray:
    grids = RNG.normal(size=(n, 2, 3))
    write_array_bag(path, {COMMAND: (np.arange(n) * 1e-3, grids)}, storage)
    return grids


# --- CDR encoding is rclpy's -----------------------------------------------------------


def test_encoding_is_what_rclpy_reads_and_writes() -> None:
    grid = RNG.normal(size=(3, 4))
    sensors = RNG.normal(size=5)
    from_numpy = deserialize_message(encode_float64_multi_array(grid, "grid"), Float64MultiArray)
    np.testing.assert_array_equal(msg_to_grid(from_numpy, (3, 4)), grid)
    from_numpy = deserialize_message(
        encode_float64_multi_array(sensors, "sensor"), Float64MultiArray
    )
    np.testing.assert_array_equal(msg_to_sensors(from_numpy, 5), sensors)
    # rclpy leaves CDR padding uninitialised: decoding must ignore it.
    payloads = [serialize_message(grid_to_msg(grid * k)) for k in range(5)]
    decoded = decode_float64_multi_arrays(COMMAND, payloads)
    np.testing.assert_array_equal(decoded, grid * np.arange(5)[:, None, None])
    decoded = decode_float64_multi_arrays(
        TEMPERATURE_RAW, [serialize_message(sensors_to_msg(sensors))]
    )
    np.testing.assert_array_equal(decoded, sensors[None])


def test_decoding_mixed_block_takes_the_slow_path_per_message() -> None:
    grids = RNG.normal(size=(3, 2, 2))
    payloads = [encode_float64_multi_array(g, "grid") for g in grids]
    # A big-endian payload has other header bytes and is parsed on its own.
    be = _big_endian_grid(grids[1])
    decoded = decode_float64_multi_arrays(COMMAND, [payloads[0], be, payloads[2]])
    np.testing.assert_array_equal(decoded, grids)


def _big_endian_grid(grid: np.ndarray) -> bytes:
    rows, cols = grid.shape
    body = struct.pack(">I", 2)
    for label, size, stride in (("row", rows, rows * cols), ("col", cols, cols)):
        raw = label.encode() + b"\0"
        body += struct.pack(">I", len(raw)) + raw
        body += bytes(-len(body) % 4) + struct.pack(">II", size, stride)
    body += struct.pack(">II", 0, grid.size)
    body += bytes(-len(body) % 8)
    return b"\0\0\0\0" + body + grid.astype(">f8").tobytes()


# --- round trips -------------------------------------------------------------------------


@pytest.mark.parametrize("storage", STORAGES)
def test_round_trip_grid_sensor_diagnostics_clock(tmp_path: Path, storage: str) -> None:
    grids = RNG.normal(size=(30, 4, 5))
    sensors = RNG.normal(size=(10, 7)) + 40.0
    bag = tmp_path / "bag"
    with BagWriter(bag, storage) as writer:
        for i, grid in enumerate(grids):  # rclpy messages, 1 kHz
            writer.write(COMMAND, 1_000_000_000 + i * 1_000_000, grid_to_msg(grid))
        for i, values in enumerate(sensors):  # CDR bytes + type name, 100 Hz, out of order
            stamp = 1_000_000_000 + (9 - i) * 10_000_000
            raw = encode_float64_multi_array(values, "sensor")
            writer.write(TEMPERATURE_RAW, stamp, raw, FLOAT64_MULTI_ARRAY)
        status = make_status("record: bag", Level.WARN, "late", {"lag": 0.25})
        writer.write(DIAGNOSTICS, 1_500_000_000, make_array(Time(sec=1, nanosec=5), [status]))
        writer.write(CLOCK, 1_000_000_000, Clock(clock=Time(sec=1)))
    assert (bag / "metadata.yaml").is_file()

    series = read_bag(bag)
    assert set(series) == {COMMAND, TEMPERATURE_RAW, DIAGNOSTICS, CLOCK}
    command = series[COMMAND]
    got = command.values
    assert got is not None
    np.testing.assert_array_equal(got, grids)
    np.testing.assert_allclose(command.times, 1.0 + np.arange(30) * 1e-3, rtol=0, atol=1e-12)
    temperatures = series[TEMPERATURE_RAW]
    got = temperatures.values
    assert got is not None
    np.testing.assert_array_equal(got, sensors[::-1])  # sorted by bag time
    assert np.all(np.diff(temperatures.times) > 0)
    (diag,) = series[DIAGNOSTICS].messages
    assert diag.status[0].name == "record: bag"
    assert diag.status[0].level == 1
    assert diag.status[0].values[0].value == "0.25"
    assert series[CLOCK].messages[0].clock.sec == 1
    assert series[CLOCK].values is None


@pytest.mark.parametrize("storage", STORAGES)
def test_bags_are_standard_rosbag2(tmp_path: Path, storage: str) -> None:
    grids = _small_bag(tmp_path / "bag", storage, n=12)
    with Reader(tmp_path / "bag") as reader:  # rosbags' own reader: metadata and storage agree
        assert reader.message_count == 12
        (conn,) = reader.connections
        assert (conn.topic, conn.msgtype) == (COMMAND, FLOAT64_MULTI_ARRAY)
        assert conn.digest.startswith("RIHS01_")
        # offered as every es_dm /dm endpoint publishes: keep last DM_DEPTH, reliable
        assert isinstance(conn.ext, ConnectionExtRosbag2)
        ((history, depth, reliability),) = [
            (q.history.name, q.depth, q.reliability.name) for q in conn.ext.offered_qos_profiles
        ]
        assert (history, depth, reliability) == ("KEEP_LAST", DM_DEPTH, "RELIABLE")
        raw = [data for _, _, data in reader.messages()]
    msgs = [deserialize_message(bytes(r), Float64MultiArray) for r in raw]
    np.testing.assert_array_equal([msg_to_grid(m, (2, 3)) for m in msgs], grids)
    meta = (tmp_path / "bag" / "metadata.yaml").read_text()
    assert "version: 9" in meta
    assert f"storage_identifier: {storage}" in meta


def test_zstd_compressed_mcap_chunks(tmp_path: Path) -> None:
    # ROS 2's MCAP plugin compresses chunks with zstd by default.
    grids = RNG.normal(size=(40, 2, 2))
    writer = Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection(COMMAND, FLOAT64_MULTI_ARRAY, typestore=TYPESTORE)
        for i, grid in enumerate(grids):
            writer.write(conn, i, encode_float64_multi_array(grid, "grid"))
    assert b"zstd" in _storage_file(tmp_path / "bag").read_bytes()
    got = read_bag(tmp_path / "bag")[COMMAND].values
    assert got is not None
    np.testing.assert_array_equal(got, grids)


def test_split_bag_reads_every_file(tmp_path: Path) -> None:
    grids = RNG.normal(size=(20, 2, 2))
    write_array_bag(tmp_path / "bag", {COMMAND: (np.arange(10.0), grids[:10])})
    write_array_bag(tmp_path / "part", {COMMAND: (np.arange(10.0, 20.0), grids[10:])})
    shutil.move(tmp_path / "part" / "part.mcap", tmp_path / "bag" / "bag_1.mcap")
    meta = tmp_path / "bag" / "metadata.yaml"
    meta.write_text(meta.read_text().replace("- bag.mcap", "- bag.mcap\n  - bag_1.mcap", 1))
    got = read_bag(tmp_path / "bag")[COMMAND].values
    assert got is not None
    np.testing.assert_array_equal(got, grids)


def test_read_selected_topics_only(tmp_path: Path) -> None:
    n = 5
    write_array_bag(
        tmp_path / "bag",
        {
            COMMAND: (np.arange(n), np.zeros((n, 2, 2))),
            TEMPERATURE_RAW: (np.arange(n), np.ones((n, 3))),
        },
    )
    series = read_bag(tmp_path / "bag", [TEMPERATURE_RAW])
    assert list(series) == [TEMPERATURE_RAW]
    values = series[TEMPERATURE_RAW].values
    assert values is not None
    assert values.shape == (n, 3)


def test_custom_type_is_read_from_the_bag_definition(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    with Writer(bag, version=9) as writer:
        conn = writer.add_connection(
            "/x", "lab_msgs/msg/Reading", msgdef="float64 x", rihs01="RIHS01_" + "0" * 64
        )
        writer.write(conn, 5, b"\0\1\0\0" + struct.pack("<d", 1.5))
    (reading,) = read_bag(bag)["/x"].messages
    assert reading.x == 1.5


# --- errors ------------------------------------------------------------------------------


def test_writer_refuses_existing_path_unknown_type_and_storage(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="exists already"):
        BagWriter(tmp_path)
    with pytest.raises(BagError, match="storage must be one of"):
        BagWriter(tmp_path / "a", "rosbag1")
    with BagWriter(tmp_path / "b") as writer:
        with pytest.raises(BagError, match="unknown message type 'lab_msgs/msg/Nope'"):
            writer.write("/x", 0, b"\0\1\0\0", "lab_msgs/msg/Nope")
        with pytest.raises(BagError, match="type_name is required"):
            writer.write("/x", 0, b"\0\1\0\0")
        writer.write("/s", 0, String(data="a"))
        with pytest.raises(BagError, match="std_msgs/msg/String in this bag"):
            writer.add_topic("/s", FLOAT64_MULTI_ARRAY)


def test_missing_path_file_and_empty_directory(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="bag not found"):
        read_bag(tmp_path / "nope")
    (tmp_path / "file.mcap").write_bytes(b"x")
    with pytest.raises(BagError, match="is a file"):
        read_bag(tmp_path / "file.mcap")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="not a bag"):
        read_bag(tmp_path / "empty")


@pytest.mark.parametrize("content", [b"", b"hello world, not a bag at all"])
def test_storage_that_is_no_bag(tmp_path: Path, content: bytes) -> None:
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "bag.mcap").write_bytes(content)
    with pytest.raises(BagError, match=r"empty|not a bag"):
        read_bag(tmp_path / "bag")


def test_missing_topic_is_named(tmp_path: Path) -> None:
    _small_bag(tmp_path / "bag")
    with pytest.raises(BagError, match=r"/dm/displacement not in bag \(has: /dm/command\)"):
        read_bag(tmp_path / "bag", [COMMAND, "/dm/displacement"])


def test_unknown_type_without_definition(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    with Writer(bag, version=9) as writer:
        conn = writer.add_connection(
            "/x", "lab_msgs/msg/Reading", msgdef="", rihs01="RIHS01_" + "0" * 64
        )
        writer.write(conn, 5, b"\0\1\0\0")
    with pytest.raises(BagError, match="unknown message type 'lab_msgs/msg/Reading'"):
        read_bag(bag)


@pytest.mark.parametrize("storage", STORAGES)
def test_truncated_storage_of_a_closed_bag(tmp_path: Path, storage: str) -> None:
    _small_bag(tmp_path / "bag", storage, n=200)
    file = _storage_file(tmp_path / "bag")
    data = file.read_bytes()
    file.write_bytes(data[: len(data) // 2])
    expected = "truncated MCAP storage" if storage == "mcap" else "corrupt sqlite3 bag"
    with pytest.raises(BagError, match=expected):
        read_bag(tmp_path / "bag")


@pytest.mark.parametrize("storage", STORAGES)
def test_corrupt_storage(tmp_path: Path, storage: str) -> None:
    _small_bag(tmp_path / "bag", storage, n=200)
    file = _storage_file(tmp_path / "bag")
    data = bytearray(file.read_bytes())
    # Overwrite the middle (MCAP: inside the chunk's records; sqlite3: b-tree pages).
    mid = len(data) // 3
    data[mid : mid + 4096] = b"\xff" * 4096
    file.write_bytes(bytes(data))
    expected = "corrupt MCAP storage" if storage == "mcap" else "corrupt sqlite3 bag"
    with pytest.raises(BagError, match=expected):
        read_bag(tmp_path / "bag")


def test_metadata_names_a_missing_file(tmp_path: Path) -> None:
    _small_bag(tmp_path / "bag")
    _storage_file(tmp_path / "bag").unlink()
    with pytest.raises(BagError, match=r"named in metadata\.yaml is missing"):
        read_bag(tmp_path / "bag")


def test_inconsistent_grid_shapes_in_one_topic(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "bag") as writer:
        writer.write(COMMAND, 1, grid_to_msg(np.zeros((2, 2))))
        writer.write(COMMAND, 2, grid_to_msg(np.zeros((2, 3))))
    with pytest.raises(
        BagError, match=r"inconsistent array shapes.*\(2, 2\).*\(2, 3\) at message 1"
    ):
        read_bag(tmp_path / "bag")


def test_layout_outside_the_contract(tmp_path: Path) -> None:
    msg = grid_to_msg(np.zeros((2, 2)))
    msg.layout.dim[0].label = "height"
    with BagWriter(tmp_path / "bag") as writer:
        writer.write(COMMAND, 1, msg)
    with pytest.raises(BagError, match=r"/dm/command: layout labels \['height', 'col'\]"):
        read_bag(tmp_path / "bag")


def test_array_helper_rejects_wrong_shapes(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"\(N, R, C\) or \(N, S\) for 3 times"):
        write_array_bag(tmp_path / "bag", {COMMAND: (np.arange(3), np.zeros((2, 2, 2)))})


# --- a writer killed mid-way -----------------------------------------------------------

_KILLED_WRITER = """
import os, signal, sys
import numpy as np
from es_msgs_py.bag import BagWriter, encode_float64_multi_array
writer = BagWriter(sys.argv[1], sys.argv[2])
for i in range(300):
    if i == 200:
        writer.flush()
    raw = encode_float64_multi_array(np.full((4, 4), float(i)), "grid")
    writer.write("/dm/command", i * 1000, raw, "std_msgs/msg/Float64MultiArray")
os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize("storage", STORAGES)
def test_killed_writer_is_readable_up_to_last_flush(tmp_path: Path, storage: str) -> None:
    bag = tmp_path / "bag"
    proc = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(bag), storage], check=False)
    assert proc.returncode == -signal.SIGKILL
    assert not (bag / "metadata.yaml").exists()
    values = read_bag(bag)[COMMAND].values
    assert values is not None
    assert len(values) == 200  # nothing after the last flush reached the file
    np.testing.assert_array_equal(values[:, 0, 0], np.arange(200.0))


def test_killed_mcap_with_a_torn_last_record(tmp_path: Path) -> None:
    _small_bag(tmp_path / "closed", "mcap", n=50)
    shutil.copytree(tmp_path / "closed", tmp_path / "killed")
    (tmp_path / "killed" / "metadata.yaml").unlink()
    file = _storage_file(tmp_path / "killed")
    # Keep the data section and a few bytes of the next record: a write cut by the kill.
    data = file.read_bytes()
    data_end = data.index(b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00")  # DataEnd record
    file.write_bytes(data[: data_end + 3])
    assert len(read_bag(tmp_path / "killed")[COMMAND]) == 50
    os.truncate(file, 20)  # only the header survived: an empty but valid bag
    assert read_bag(tmp_path / "killed") == {}
