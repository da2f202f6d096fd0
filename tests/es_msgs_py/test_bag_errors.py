"""The bag package's shape: specific error classes, the storage table, the public faces.

Every failure of bag I/O raises a specific subclass of ``BagError`` (itself a ``ValueError``)
that names what went wrong; ``tests/es_msgs_py/test_bag.py`` checks the messages.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Writer
from rosbags.typesys import Stores, get_typestore

import es_msgs_py
import es_msgs_py.bag
import es_msgs_py.errors
from es_msgs_py.arrays import LayoutError
from es_msgs_py.bag import (
    FLOAT64_MULTI_ARRAY,
    STORAGE_PLUGINS,
    STORAGES,
    BagError,
    BagExistsError,
    BagLayoutError,
    BagNotFoundError,
    BagWriteError,
    BagWriter,
    CorruptBagError,
    MissingTopicError,
    NotABagError,
    UnknownMessageTypeError,
    UnsupportedBagError,
    encode_float64_multi_array,
    read_bag,
    write_array_bag,
)

COMMAND = "/dm/command"


def _bag(path: Path, storage: str = "mcap", n: int = 50) -> Path:
    write_array_bag(path, {COMMAND: (np.arange(n) * 1e-3, np.ones((n, 2, 2)))}, storage)
    return path


def _storage_file(bag: Path) -> Path:
    (file,) = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    return file


def test_every_error_is_a_value_error_and_every_bag_error_a_bag_error() -> None:
    for name in es_msgs_py.errors.__all__:
        cls = getattr(es_msgs_py.errors, name)
        assert issubclass(cls, ValueError), name
    for name in es_msgs_py.bag.errors.__all__:
        assert issubclass(getattr(es_msgs_py.bag.errors, name), BagError), name
    assert set(es_msgs_py.errors.__all__) - set(es_msgs_py.bag.errors.__all__) == {"LayoutError"}
    assert issubclass(BagLayoutError, LayoutError)  # a layout problem, wherever it shows
    assert issubclass(BagExistsError, BagWriteError)


def test_reader_errors_name_the_failure(tmp_path: Path) -> None:
    with pytest.raises(BagNotFoundError):
        read_bag(tmp_path / "nope")
    (tmp_path / "file.mcap").write_bytes(b"x")
    with pytest.raises(NotABagError):
        read_bag(tmp_path / "file.mcap")
    (tmp_path / "empty").mkdir()
    with pytest.raises(NotABagError):
        read_bag(tmp_path / "empty")
    bag = _bag(tmp_path / "bag")
    with pytest.raises(MissingTopicError):
        read_bag(bag, [COMMAND, "/dm/displacement"])
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(NotABagError, match="is not rosbag2 metadata"):
        read_bag(bag)


@pytest.mark.parametrize("storage", STORAGES)
def test_truncated_closed_bag_is_corrupt(tmp_path: Path, storage: str) -> None:
    bag = _bag(tmp_path / "bag", storage, n=200)
    file = _storage_file(bag)
    file.write_bytes(file.read_bytes()[: file.stat().st_size // 2])
    with pytest.raises(CorruptBagError):
        read_bag(bag)


def test_compressed_bag_is_unsupported(tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    writer = Writer(tmp_path / "bag", version=9)
    writer.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection(COMMAND, FLOAT64_MULTI_ARRAY, typestore=store)
        writer.write(conn, 1, encode_float64_multi_array(np.zeros((2, 2)), "grid"))
    with pytest.raises(UnsupportedBagError, match="compressed bags are not supported"):
        read_bag(tmp_path / "bag")


def test_unknown_types_and_layouts(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "bag") as writer:
        with pytest.raises(UnknownMessageTypeError):
            writer.add_topic("/x", "lab_msgs/msg/Nope")
        grid = encode_float64_multi_array(np.zeros((2, 2)), "grid")
        writer.write(COMMAND, 1, grid, FLOAT64_MULTI_ARRAY)
        sensors = encode_float64_multi_array(np.zeros(3), "sensor")
        writer.write(COMMAND, 2, sensors, FLOAT64_MULTI_ARRAY)
    with pytest.raises(BagLayoutError, match="inconsistent array shapes"):
        read_bag(tmp_path / "bag")
    with pytest.raises(LayoutError):  # caught as a layout problem too
        encode_float64_multi_array(np.zeros((2, 2, 2)), "grid")


def test_writer_errors(tmp_path: Path) -> None:
    with pytest.raises(BagExistsError):
        BagWriter(tmp_path)
    with pytest.raises(BagWriteError):
        BagWriter(tmp_path / "a", "rosbag1")
    writer = BagWriter(tmp_path / "b")
    writer.close()
    with pytest.raises(BagWriteError, match="is closed"):
        writer.write(COMMAND, 0, b"\0\1\0\0", FLOAT64_MULTI_ARRAY)


def test_storage_table_matches_what_the_writer_writes(tmp_path: Path) -> None:
    """Each storage id the writer offers has a reader plugin recognising its files."""
    assert set(STORAGE_PLUGINS) == set(STORAGES) == {"mcap", "sqlite3"}
    for storage in STORAGES:
        file = _storage_file(_bag(tmp_path / storage, storage))
        plugin = STORAGE_PLUGINS[storage]
        assert file.suffix == plugin.suffix
        assert file.read_bytes().startswith(plugin.magic)
        assert not any(
            file.read_bytes().startswith(other.magic)
            for sid, other in STORAGE_PLUGINS.items()
            if sid != storage
        )


def test_public_faces_resolve() -> None:
    for name in es_msgs_py.bag.__all__:
        assert hasattr(es_msgs_py.bag, name), name
    for name in es_msgs_py.__all__:
        assert getattr(es_msgs_py, name) is not None, name
    with pytest.raises(AttributeError):
        _ = es_msgs_py.no_such_module  # type: ignore[attr-defined]


def test_package_import_is_cheap_and_needs_no_rclpy() -> None:
    """``import es_msgs_py`` loads none of its modules; bag and errors load without rclpy."""
    code = (
        "import sys, es_msgs_py\n"
        "assert not any(m.startswith(('es_msgs_py.', 'numpy', 'rclpy')) for m in sys.modules)\n"
        "import es_msgs_py.errors\n"
        "assert 'numpy' not in sys.modules\n"
        "from es_msgs_py.bag import read_bag\n"
        "assert not any(m.startswith(('rclpy', 'std_msgs')) for m in sys.modules)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=os.environ, check=False
    )
    assert proc.returncode == 0, proc.stderr
