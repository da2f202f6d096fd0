"""Read and write rosbag2 bags of the es_dm contract (pure: rosbags and numpy, no rclpy).

Bags are rosbag2 directories (``metadata.yaml`` + one storage file, MCAP by default or
sqlite3) written with the ``rosbags`` library, so ROS 2 Jazzy tools read them.

Reading turns each contract array topic (``std_msgs/msg/Float64MultiArray``) into one float64
array, (N, R, C) for grids and (N, S) for sensor vectors: the CDR headers are checked in
blocks with numpy and each payload's values are copied with one memcpy (no per-element
Python work). Other types come back as deserialized ``rosbags`` messages.

A bag whose writer died (SIGKILL, power loss) has no ``metadata.yaml``; its storage file
holds everything flushed before the end (:meth:`BagWriter.flush`). :func:`read_bag` reads
such a bag from the storage alone, up to the last complete record. A bag *with*
``metadata.yaml`` was closed cleanly, so a truncated or damaged storage file is an error.
"""

from __future__ import annotations

import mmap
import sqlite3
import struct
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Final, Literal, Self

import numpy as np
import numpy.typing as npt
import yaml
from rosbags.interfaces import (
    Connection,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, TypesysError, get_types_from_idl, get_types_from_msg
from rosbags.typesys import get_typestore as _get_typestore
from rosbags.typesys.store import Typestore

FLOAT64_MULTI_ARRAY: Final = "std_msgs/msg/Float64MultiArray"
#: rosbag2 metadata version of ROS 2 Jazzy.
BAG_VERSION: Final = 9
STORAGES: Final = ("mcap", "sqlite3")

# The contract's labels, as in es_msgs_py.arrays (not imported: it needs the ROS message
# classes, and this module must work with numpy and rosbags alone).
ROW_LABEL: Final = "row"
COL_LABEL: Final = "col"
SENSOR_LABEL: Final = "sensor"

FloatArray = npt.NDArray[np.float64]
Storage = Literal["mcap", "sqlite3"]

_MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
_SQLITE_MAGIC: Final = b"SQLite format 3\x00"
_CDR_LE: Final = b"\x00\x01\x00\x00"
_CDR_BE: Final = b"\x00\x00\x00\x00"
# Messages whose headers are compared in one numpy operation.
_BLOCK_MESSAGES: Final = 4096


class BagError(ValueError):
    """A bag cannot be read or written; the message is one readable line."""


@dataclass
class TopicSeries:
    """One topic of a bag.

    ``times`` are the bag's per-message timestamps in seconds (float64, shape (N,)).
    ``values`` holds contract arrays, shape (N, R, C) for grids or (N, S) for sensors ((0, 0)
    for a topic without messages), and is ``None`` for other types; ``messages`` then holds
    the deserialized ``rosbags`` messages.
    """

    topic: str
    type_name: str
    times: FloatArray
    values: FloatArray | None = None
    messages: list[Any] = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.times.size)


def _typestore() -> Typestore:
    return _get_typestore(Stores.ROS2_JAZZY)


# --------------------------------------------------------------------------------------
# Float64MultiArray <-> CDR with numpy


def _align(offset: int, size: int) -> int:
    return offset + (-offset % size)


def encode_float64_multi_array(values: npt.ArrayLike, kind: Literal["grid", "sensor"]) -> bytes:
    """Return the CDR payload of a contract ``Float64MultiArray`` holding ``values``.

    ``kind="grid"`` takes an (R, C) array, ``kind="sensor"`` an (S,) vector. The bytes equal
    rclpy's ``serialize_message`` of the same message except for the CDR padding, which is
    zero here and undefined there.
    """
    arr = np.ascontiguousarray(values, dtype="<f8")
    if kind == "grid":
        if arr.ndim != 2:
            raise BagError(f"a grid must be 2-D, got shape {arr.shape}")
        rows, cols = arr.shape
        dims = [(ROW_LABEL, rows, rows * cols), (COL_LABEL, cols, cols)]
    else:
        if arr.ndim != 1:
            raise BagError(f"a sensor vector must be 1-D, got shape {arr.shape}")
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
        labels = tuple(label for label, _, _ in self.dims)
        sizes = tuple(size for _, size, _ in self.dims)
        strides = tuple(stride for _, _, stride in self.dims)
        if labels == (ROW_LABEL, COL_LABEL):
            rows, cols = sizes
            if strides != (rows * cols, cols):
                raise BagError(f"{topic}: grid strides {strides} do not match {rows} x {cols}")
        elif labels == (SENSOR_LABEL,):
            if strides != sizes:
                raise BagError(f"{topic}: sensor stride {strides[0]} != size {sizes[0]}")
        else:
            raise BagError(
                f"{topic}: layout labels {list(labels)} are neither ['row', 'col'] nor ['sensor']"
            )
        if self.data_offset != 0:
            raise BagError(f"{topic}: data_offset is {self.data_offset}, the contract needs 0")
        if self.count != int(np.prod(sizes)):
            raise BagError(f"{topic}: {self.count} values for a layout of shape {sizes}")
        return sizes


def _parse_array_header(payload: memoryview, topic: str) -> _ArrayHeader:
    """Parse the CDR layout of a Float64MultiArray payload (not its values)."""
    try:
        if bytes(payload[:4]) not in (_CDR_LE, _CDR_BE):
            raise BagError(f"{topic}: unsupported CDR encapsulation {bytes(payload[:4]).hex()}")
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
        raise BagError(f"{topic}: truncated or corrupt Float64MultiArray payload") from None
    if 4 + pos + 8 * count != len(payload):
        raise BagError(f"{topic}: payload of {len(payload)} bytes does not hold {count} values")
    return _ArrayHeader(tuple(dims), data_offset, count, 4 + pos, order + "f8", tuple(significant))


def decode_float64_multi_arrays(topic: str, payloads: Sequence[memoryview | bytes]) -> FloatArray:
    """Decode contract ``Float64MultiArray`` payloads into one (N, R, C) or (N, S) array.

    Payloads sharing the first one's layout (the normal case) are checked in blocks with one
    vectorised comparison of their headers, then copied straight into the result (one
    memcpy per message, no intermediate buffer: bags of a few GB stay within memory).

    Raises:
        BagError: a layout is not the contract's, or shapes differ within the topic.

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
                raise BagError(
                    f"{topic}: inconsistent array shapes in one topic: {shape} at message 0, "
                    f"{this.shape(topic)} at message {i}"
                )
            out[i] = np.frombuffer(payload, this.dtype, this.count, this.data_start)
    return out.reshape(len(payloads), *shape)


# --------------------------------------------------------------------------------------
# Writing


def _default_qos() -> list[Qos]:
    never = QosTime(sec=0, nsec=0)
    return [
        Qos(
            QosHistory.KEEP_LAST,
            10,
            QosReliability.RELIABLE,
            QosDurability.VOLATILE,
            never,
            never,
            QosLiveliness.AUTOMATIC,
            never,
            avoid_ros_namespace_conventions=False,
        )
    ]


def ros_type_name(msg: object) -> str:
    """Return the ROS 2 type name (``pkg/msg/Name``) of an rclpy message instance."""
    module = type(msg).__module__.split(".")
    if len(module) < 2 or module[1] != "msg":
        raise BagError(f"not an rclpy message: {type(msg).__name__}")
    return f"{module[0]}/msg/{type(msg).__name__}"


class BagWriter:
    """Write a rosbag2 bag: MCAP (default) or sqlite3 storage.

    ``write(topic, t_ns, msg)`` takes an rclpy message, or CDR bytes with ``type_name``.
    Topics are registered on first use (or with :meth:`add_topic`, to give their QoS).
    :meth:`flush` makes everything written so far durable in the storage file, so a bag
    whose process is killed stays readable up to the last flush; :meth:`close` finishes the
    storage and writes ``metadata.yaml``.
    """

    def __init__(self, path: str | Path, storage: Storage | str = "mcap") -> None:
        """Create the bag directory ``path`` (which must not exist) and open its storage."""
        if storage not in STORAGES:
            raise BagError(f"storage must be one of {list(STORAGES)}, got {storage!r}")
        self.path = Path(path)
        self.storage: str = storage
        if self.path.exists():
            raise BagError(f"{self.path} exists already; a bag is never overwritten")
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=plugin)
        self._typestore = _typestore()
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}
        try:
            self._writer.open()
        except (WriterError, OSError) as err:
            raise BagError(f"cannot create bag {self.path}: {err}") from None
        self._open = True

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def add_topic(self, topic: str, type_name: str, qos: Sequence[Qos] | None = None) -> None:
        """Register ``topic`` with its type (and offered QoS, default the /dm contract QoS).

        Raises:
            BagError: the type is unknown, or the topic was registered with another type.

        """
        known = self._connections.get(topic)
        if known is not None:
            if known.msgtype != type_name:
                raise BagError(f"{topic} is {known.msgtype} in this bag, not {type_name}")
            return
        if type_name not in self._typestore.fielddefs:
            raise BagError(f"unknown message type {type_name!r} for topic {topic}")
        self._connections[topic] = self._writer.add_connection(
            topic,
            type_name,
            typestore=self._typestore,
            offered_qos_profiles=list(qos) if qos is not None else _default_qos(),
        )
        self.counts[topic] = 0

    def write(self, topic: str, t_ns: int, msg: object, type_name: str | None = None) -> None:
        """Write one message stamped ``t_ns`` (ns).

        Args:
            topic: topic name.
            t_ns: the bag timestamp in nanoseconds (receive time, sim time under /clock).
            msg: an rclpy message, or its CDR serialization (``bytes``/``memoryview``).
            type_name: the ROS 2 type name; required for bytes, derived for a message.

        """
        if not self._open:
            raise BagError(f"bag {self.path} is closed")
        if isinstance(msg, bytes | bytearray | memoryview):
            if type_name is None:
                raise BagError(f"{topic}: type_name is required for serialized data")
            data: bytes | memoryview = msg if isinstance(msg, bytes | memoryview) else bytes(msg)
        else:
            from rclpy.serialization import serialize_message

            type_name = type_name or ros_type_name(msg)
            data = serialize_message(msg)
        if topic not in self._connections:
            self.add_topic(topic, type_name)
        self._writer.write(self._connections[topic], int(t_ns), data)
        self.counts[topic] += 1

    def flush(self) -> None:
        """Make every message written so far durable in the storage file.

        MCAP: the pending chunk is closed and the file buffer flushed; sqlite3: the open
        transaction is committed. Uses the rosbags storage writers' attributes (rosbags 0.11).
        """
        storage = self._writer.storage
        if storage is None:
            return
        bio = getattr(storage, "bio", None)
        if bio is not None:
            if storage.chunk.bio.tell():  # type: ignore[attr-defined]
                storage.close_chunk()  # type: ignore[attr-defined]
            bio.flush()
        else:
            storage.conn.commit()  # type: ignore[attr-defined]

    def close(self) -> None:
        """Finish the storage and write ``metadata.yaml``; later calls do nothing."""
        if self._open:
            self._open = False
            self._writer.close()


def write_array_bag(
    path: str | Path,
    series: Mapping[str, tuple[npt.ArrayLike, npt.ArrayLike]],
    storage: Storage | str = "mcap",
) -> None:
    """Write contract arrays as a bag: ``{topic: (times_s (N,), values (N, R, C) or (N, S))}``.

    Meant for test data and tools; messages are encoded with numpy (no rclpy needed).
    """
    checked = []
    for topic, (times, values) in series.items():
        t_ns = np.round(np.asarray(times, dtype=np.float64) * 1e9).astype(np.int64)
        arr = np.asarray(values, dtype=np.float64)
        if t_ns.ndim != 1 or arr.ndim not in (2, 3) or len(arr) != len(t_ns):
            raise BagError(
                f"{topic}: need values of shape (N, R, C) or (N, S) for {t_ns.size} "
                f"times, got {arr.shape}"
            )
        checked.append((topic, t_ns, arr))
    with BagWriter(path, storage) as bag:
        for topic, t_ns, arr in checked:
            kind: Literal["grid", "sensor"] = "grid" if arr.ndim == 3 else "sensor"
            bag.add_topic(topic, FLOAT64_MULTI_ARRAY)
            for stamp, value in zip(t_ns, arr, strict=True):
                raw = encode_float64_multi_array(value, kind)
                bag.write(topic, int(stamp), raw, FLOAT64_MULTI_ARRAY)


# --------------------------------------------------------------------------------------
# Reading


@dataclass
class _RawTopic:
    type_name: str
    definition: tuple[str, str] | None  # (encoding, text) of the message definition
    stamps: list[int] = field(default_factory=list)
    payloads: list[memoryview | bytes] = field(default_factory=list)


def _storage_files(path: Path) -> tuple[list[Path], bool]:
    """Return the bag's storage files (several for a split bag) and whether it was closed."""
    if not path.exists():
        raise BagError(f"bag not found: {path}")
    if path.is_file():
        raise BagError(f"{path} is a file; a rosbag2 bag is a directory with metadata.yaml")
    if not (path / "metadata.yaml").is_file():
        files = sorted(p for p in path.iterdir() if p.suffix in (".mcap", ".db3"))
        if not files:
            raise BagError(f"not a bag: {path} has no metadata.yaml and no .mcap/.db3 file")
        return files, False
    try:
        meta = yaml.safe_load((path / "metadata.yaml").read_text())
        info = meta["rosbag2_bagfile_information"]
        names = [str(n) for n in info["relative_file_paths"]]
    except (yaml.YAMLError, KeyError, TypeError, UnicodeDecodeError):
        raise BagError(f"{path}/metadata.yaml is not rosbag2 metadata") from None
    if info.get("compression_mode"):
        raise BagError(f"{path}: file- or message-compressed bags are not supported")
    for name in names:
        if not (path / name).is_file():
            raise BagError(f"{path}: storage file {name} named in metadata.yaml is missing")
    return [path / name for name in names], True


def _read_storage(file: Path, strict: bool, wanted: set[str] | None) -> dict[str, _RawTopic]:
    with file.open("rb") as handle:
        head = handle.read(16)
    if head[:8] == _MCAP_MAGIC:
        return _read_mcap(file, strict, wanted)
    if head == _SQLITE_MAGIC:
        return _read_sqlite(file, strict, wanted)
    if not head:
        raise BagError(f"{file} is empty")
    raise BagError(f"not a bag: {file} is neither MCAP nor sqlite3")


def _read_sqlite(file: Path, strict: bool, wanted: set[str] | None) -> dict[str, _RawTopic]:
    topics: dict[str, _RawTopic] = {}
    try:
        with file.open("rb") as handle:
            if handle.read(16) != _SQLITE_MAGIC:
                raise BagError(f"{file} is not an sqlite3 bag (bad file header)")
        # Read-write open: a killed writer leaves a hot journal that sqlite rolls back.
        conn = sqlite3.connect(f"file:{file}?mode={'ro' if strict else 'rw'}", uri=True)
        try:
            definitions = {
                row[0]: (row[1], row[2])
                for row in conn.execute(
                    "SELECT topic_type, encoding, encoded_message_definition "
                    "FROM message_definitions"
                )
            }
            ids: dict[int, str] = {}
            for topic_id, name, type_name in conn.execute("SELECT id, name, type FROM topics"):
                if wanted is None or name in wanted:
                    ids[topic_id] = name
                    topics[name] = _RawTopic(type_name, definitions.get(type_name))
            tables = {row[0] for row in conn.execute("SELECT name FROM sqlite_master")}
            # Jazzy writes a metadata row on close; older distributions have no such table.
            closed = (
                "metadata" not in tables
                or conn.execute("SELECT count(*) FROM metadata").fetchone()[0]
            )
            if strict and not closed:
                raise BagError(f"{file}: truncated sqlite3 storage (it was never closed)")
            rows = conn.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id")
            for topic_id, stamp, data in rows:
                name = ids.get(topic_id)
                if name is not None:
                    topics[name].stamps.append(stamp)
                    topics[name].payloads.append(data)
        finally:
            conn.close()
    except sqlite3.DatabaseError as err:
        raise BagError(f"{file}: corrupt sqlite3 bag ({err})") from None
    return topics


class _McapScan:
    """Sequential MCAP record scan (chunks uncompressed or zstd), tolerant of a cut tail."""

    def __init__(self, file: Path, strict: bool, wanted: set[str] | None) -> None:
        self.file = file
        self.strict = strict
        self.wanted = wanted
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self.channels: dict[int, str] = {}
        self.topics: dict[str, _RawTopic] = {}
        self.complete = False

    def corrupt(self, what: str) -> BagError:
        return BagError(f"{self.file}: corrupt MCAP storage ({what})")

    def run(self, data: memoryview) -> None:
        if len(data) < 8 or bytes(data[:8]) != _MCAP_MAGIC:
            raise BagError(f"{self.file} is not an MCAP bag (bad file magic)")
        if self.strict and (len(data) < 16 or bytes(data[-8:]) != _MCAP_MAGIC):
            raise BagError(f"{self.file}: truncated MCAP storage (no footer)")
        self.records(data, 8, top_level=True)
        if self.strict and not self.complete:
            raise BagError(f"{self.file}: truncated MCAP storage (no data end record)")

    def records(self, data: memoryview, pos: int, top_level: bool) -> None:
        end = len(data)
        while pos < end:
            if pos + 9 > end:
                return self.cut(top_level, pos)
            op = data[pos]
            if op == 0 or 0x10 <= op < 0x80:  # 0x80-0xff are user-defined records
                raise self.corrupt(f"invalid record opcode 0x{op:02x} at byte {pos}")
            (length,) = struct.unpack_from("<Q", data, pos + 1)
            body_start = pos + 9
            if body_start + length > end:
                return self.cut(top_level, pos)
            body = data[body_start : body_start + length]
            pos = body_start + length
            if op in {0x0F, 0x02}:  # data end / footer: the data section is over
                self.complete = True
                return None
            self.record(op, body)
        return None

    def cut(self, top_level: bool, pos: int) -> None:
        """Handle a record running past the end: a killed writer's torn tail, else damage."""
        if not top_level:
            raise self.corrupt(f"record at byte {pos} of a chunk runs past the chunk's end")
        if self.strict:
            raise BagError(f"{self.file}: truncated MCAP storage (record at byte {pos} is cut)")

    def record(self, op: int, body: memoryview) -> None:
        try:
            if op == 0x03:  # schema
                (schema_id,) = struct.unpack_from("<H", body, 0)
                name, pos = _mcap_string(body, 2)
                encoding, pos = _mcap_string(body, pos)
                (size,) = struct.unpack_from("<I", body, pos)
                text = bytes(body[pos + 4 : pos + 4 + size]).decode()
                self.schemas[schema_id] = (name, encoding, text)
            elif op == 0x04:  # channel
                channel_id, schema_id = struct.unpack_from("<HH", body, 0)
                topic, _ = _mcap_string(body, 4)
                if self.wanted is None or topic in self.wanted:
                    schema = self.schemas.get(schema_id)
                    if schema is None:
                        raise self.corrupt(f"channel {topic} refers to unknown schema {schema_id}")
                    self.channels[channel_id] = topic
                    self.topics.setdefault(topic, _RawTopic(schema[0], (schema[1], schema[2])))
            elif op == 0x05:  # message
                channel_id, _, stamp = struct.unpack_from("<HIQ", body, 0)
                channel_topic = self.channels.get(channel_id)
                if channel_topic is not None:
                    raw = self.topics[channel_topic]
                    raw.stamps.append(stamp)
                    raw.payloads.append(body[22:])
            elif op == 0x06:  # chunk
                self.chunk(body)
        except (struct.error, UnicodeDecodeError):
            raise self.corrupt(f"malformed record 0x{op:02x}") from None

    def chunk(self, body: memoryview) -> None:
        _, _, uncompressed_size, _ = struct.unpack_from("<QQQI", body, 0)
        compression, pos = _mcap_string(body, 28)
        (size,) = struct.unpack_from("<Q", body, pos)
        records = body[pos + 8 : pos + 8 + size]
        if compression == "zstd":
            if sys.version_info >= (3, 14):
                from compression import zstd  # pragma: no cover
            else:
                from backports import zstd
            records = memoryview(zstd.decompress(records))
        elif compression:
            raise BagError(f"{self.file}: unsupported MCAP chunk compression {compression!r}")
        if len(records) != uncompressed_size:
            raise self.corrupt("chunk size mismatch")
        self.records(records, 0, top_level=False)


def _mcap_string(body: memoryview, pos: int) -> tuple[str, int]:
    (size,) = struct.unpack_from("<I", body, pos)
    if pos + 4 + size > len(body):
        raise struct.error("string beyond record")
    return bytes(body[pos + 4 : pos + 4 + size]).decode(), pos + 4 + size


def _read_mcap(file: Path, strict: bool, wanted: set[str] | None) -> dict[str, _RawTopic]:
    """Return the topics of an MCAP file; payloads are views into a memory map of it.

    The map is never closed explicitly: it is unmapped when the last view is gone, which
    also holds for views kept alive by the traceback of an error.
    """
    if file.stat().st_size == 0:
        raise BagError(f"{file} is empty")
    with file.open("rb") as handle:
        mapped = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
    scan = _McapScan(file, strict, wanted)
    scan.run(memoryview(mapped))
    return scan.topics


def _register_type(store: Typestore, raw: _RawTopic, topic: str) -> None:
    if raw.type_name in store.fielddefs:
        return
    if raw.definition is None or not raw.definition[1].strip():
        raise BagError(f"{topic}: unknown message type {raw.type_name!r} (no definition in bag)")
    encoding, text = raw.definition
    try:
        types = (
            get_types_from_idl(text)
            if encoding == "ros2idl"
            else get_types_from_msg(text, raw.type_name)
        )
        store.register(types)
    except TypesysError as err:
        raise BagError(f"{topic}: unknown message type {raw.type_name!r}: {err}") from None


def read_bag(path: str | Path, topics: Iterable[str] | None = None) -> dict[str, TopicSeries]:
    """Read a bag (MCAP or sqlite3) into one :class:`TopicSeries` per topic.

    Args:
        path: the bag directory.
        topics: the topics to read; ``None`` reads every topic of the bag.

    Raises:
        BagError: the path is missing or not a bag, its storage is corrupt or (for a cleanly
            closed bag) truncated, a requested topic is missing, a type is unknown, or an
            array topic breaks the contract layout or changes shape.

    """
    bag = Path(path)
    wanted = set(topics) if topics is not None else None
    files, strict = _storage_files(bag)
    raw_topics: dict[str, _RawTopic] = {}
    for file in files:
        for topic, raw in _read_storage(file, strict, wanted).items():
            known = raw_topics.setdefault(topic, raw)
            if known is raw:
                continue
            if known.type_name != raw.type_name:
                raise BagError(
                    f"{topic} is {known.type_name} in one file, {raw.type_name} in {file}"
                )
            known.stamps.extend(raw.stamps)
            known.payloads.extend(raw.payloads)
    return _to_series(bag, raw_topics, wanted)


def _to_series(
    bag: Path, raw_topics: dict[str, _RawTopic], wanted: set[str] | None
) -> dict[str, TopicSeries]:
    if wanted is not None:
        missing = sorted(wanted - raw_topics.keys())
        if missing:
            raise BagError(
                f"{bag}: topic(s) {', '.join(missing)} not in bag "
                f"(has: {', '.join(sorted(raw_topics)) or 'nothing'})"
            )
    store = _typestore()
    result: dict[str, TopicSeries] = {}
    for topic, raw in sorted(raw_topics.items()):
        stamps = np.asarray(raw.stamps, dtype=np.int64)
        order = np.argsort(stamps, kind="stable")
        payloads = [raw.payloads[i] for i in order]
        series = TopicSeries(topic, raw.type_name, stamps[order].astype(np.float64) * 1e-9)
        if raw.type_name == FLOAT64_MULTI_ARRAY:
            series.values = decode_float64_multi_arrays(topic, payloads)
        else:
            _register_type(store, raw, topic)
            try:
                # bytes(): deserialized arrays may be views into the payload.
                series.messages = [store.deserialize_cdr(bytes(p), raw.type_name) for p in payloads]
            except Exception as err:  # rosbags raises assorted errors on bad CDR
                raise BagError(f"{topic}: corrupt {raw.type_name} message ({err})") from None
        result[topic] = series
    return result
