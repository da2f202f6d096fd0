"""Read the MCAP storage of a rosbag2 bag by a sequential scan of its records.

The scan needs no summary section or index, so it also reads the storage of a bag whose
writer was killed (no ``metadata.yaml``, no footer, maybe a torn last record) up to the last
complete record. rosbags cannot read such a file: its public ``Reader`` needs
``metadata.yaml`` and its MCAP storage reader the file's footer, which a killed writer never
writes. So the scan follows the MCAP format specification (https://mcap.dev/spec) itself:
chunks uncompressed or zstd, as rosbag2 and rosbags write them.
"""

from __future__ import annotations

import mmap
import struct
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Final

from es_msgs_py.bag.errors import CorruptBagError, NotABagError, UnsupportedBagError
from es_msgs_py.bag.raw import RawTopic, StorageFormat

__all__ = ["FORMAT", "MAGIC", "STORAGE_ID", "iter_read", "read"]

#: rosbag2's storage identifier.
STORAGE_ID: Final = "mcap"
#: The magic bytes opening (and closing) every MCAP file.
MAGIC: Final = b"\x89MCAP0\r\n"

_OP_DATA_OVER: Final = frozenset({0x0F, 0x02})  # data end, footer: the data section ends
_OP_SCHEMA: Final = 0x03
_OP_CHANNEL: Final = 0x04
_OP_MESSAGE: Final = 0x05
_OP_CHUNK: Final = 0x06


def _string(body: memoryview, pos: int) -> tuple[str, int]:
    (size,) = struct.unpack_from("<I", body, pos)
    if pos + 4 + size > len(body):
        raise struct.error("string beyond record")
    return bytes(body[pos + 4 : pos + 4 + size]).decode(), pos + 4 + size


class _Scan:
    """Sequential MCAP record scan (chunks uncompressed or zstd), tolerant of a cut tail."""

    def __init__(self, file: Path, strict: bool, wanted: set[str] | None) -> None:
        self.file = file
        self.strict = strict
        self.wanted = wanted
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self.channels: dict[int, str] = {}
        self.topics: dict[str, RawTopic] = {}
        self.complete = False

    def corrupt(self, what: str) -> CorruptBagError:
        return CorruptBagError(f"{self.file}: corrupt MCAP storage ({what})")

    def run(self, data: memoryview) -> None:
        if len(data) < 8 or bytes(data[:8]) != MAGIC:
            raise NotABagError(f"{self.file} is not an MCAP bag (bad file magic)")
        if self.strict and (len(data) < 16 or bytes(data[-8:]) != MAGIC):
            raise CorruptBagError(f"{self.file}: truncated MCAP storage (no footer)")
        self.records(data, 8, top_level=True)
        if self.strict and not self.complete:
            raise CorruptBagError(f"{self.file}: truncated MCAP storage (no data end record)")

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
            if op in _OP_DATA_OVER:
                self.complete = True
                return None
            self.record(op, body)
        return None

    def cut(self, top_level: bool, pos: int) -> None:
        """Handle a record running past the end: a killed writer's torn tail, else damage."""
        if not top_level:
            raise self.corrupt(f"record at byte {pos} of a chunk runs past the chunk's end")
        if self.strict:
            raise CorruptBagError(
                f"{self.file}: truncated MCAP storage (record at byte {pos} is cut)"
            )

    def record(self, op: int, body: memoryview) -> None:
        try:
            if op == _OP_SCHEMA:
                (schema_id,) = struct.unpack_from("<H", body, 0)
                name, pos = _string(body, 2)
                encoding, pos = _string(body, pos)
                (size,) = struct.unpack_from("<I", body, pos)
                text = bytes(body[pos + 4 : pos + 4 + size]).decode()
                self.schemas[schema_id] = (name, encoding, text)
            elif op == _OP_CHANNEL:
                channel_id, schema_id = struct.unpack_from("<HH", body, 0)
                topic, _ = _string(body, 4)
                if self.wanted is None or topic in self.wanted:
                    schema = self.schemas.get(schema_id)
                    if schema is None:
                        raise self.corrupt(f"channel {topic} refers to unknown schema {schema_id}")
                    self.channels[channel_id] = topic
                    self.topics.setdefault(topic, RawTopic(schema[0], (schema[1], schema[2])))
            elif op == _OP_MESSAGE:
                channel_id, _, stamp = struct.unpack_from("<HIQ", body, 0)
                channel_topic = self.channels.get(channel_id)
                if channel_topic is not None:
                    raw = self.topics[channel_topic]
                    raw.stamps.append(stamp)
                    raw.payloads.append(body[22:])
            elif op == _OP_CHUNK:
                self.chunk(body)
        except (struct.error, UnicodeDecodeError):
            raise self.corrupt(f"malformed record 0x{op:02x}") from None

    def chunk(self, body: memoryview) -> None:
        _, _, uncompressed_size, _ = struct.unpack_from("<QQQI", body, 0)
        compression, pos = _string(body, 28)
        (size,) = struct.unpack_from("<Q", body, pos)
        records = body[pos + 8 : pos + 8 + size]
        if compression == "zstd":
            if sys.version_info >= (3, 14):
                from compression import zstd  # pragma: no cover
            else:
                from backports import zstd
            records = memoryview(zstd.decompress(records))
        elif compression:
            raise UnsupportedBagError(
                f"{self.file}: unsupported MCAP chunk compression {compression!r}"
            )
        if len(records) != uncompressed_size:
            raise self.corrupt("chunk size mismatch")
        self.records(records, 0, top_level=False)


def read(file: Path, strict: bool, wanted: set[str] | None) -> dict[str, RawTopic]:
    """Return the topics of an MCAP file (see :data:`~es_msgs_py.bag.raw.StorageReader`).

    Payloads are views into a memory map of the file. The map is never closed explicitly:
    it is unmapped when the last view is gone, which also holds for views kept alive by the
    traceback of an error.

    Raises:
        NotABagError: the file is empty or does not start with the MCAP magic.
        CorruptBagError: a record is damaged, or (``strict``) the file is truncated.
        UnsupportedBagError: a chunk is compressed with something other than zstd.

    """
    if file.stat().st_size == 0:
        raise NotABagError(f"{file} is empty")
    with file.open("rb") as handle:
        mapped = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
    scan = _Scan(file, strict, wanted)
    scan.run(memoryview(mapped))
    return scan.topics


def iter_read(
    file: Path, strict: bool, wanted: set[str] | None, batch_bytes: int
) -> Iterator[dict[str, RawTopic]]:
    """Yield the topics of an MCAP file in batches of about ``batch_bytes`` of records.

    The file is read record by record (no memory map), so at most one batch and one chunk
    are held: memory does not grow with the file. Each batch holds the messages read since
    the previous one, in file order (topics without messages in the batch are left out).

    Raises:
        NotABagError: the file is empty or does not start with the MCAP magic.
        CorruptBagError: a record is damaged, or (``strict``) the file is truncated.
        UnsupportedBagError: a chunk is compressed with something other than zstd.

    """
    size = file.stat().st_size
    if size == 0:
        raise NotABagError(f"{file} is empty")
    scan = _Scan(file, strict, wanted)
    with file.open("rb") as handle:
        if handle.read(8) != MAGIC:
            raise NotABagError(f"{file} is not an MCAP bag (bad file magic)")
        if strict:
            handle.seek(size - 8)
            if size < 16 or handle.read(8) != MAGIC:
                raise CorruptBagError(f"{file}: truncated MCAP storage (no footer)")
            handle.seek(8)
        pos, pending = 8, 0
        while True:
            head = handle.read(9)
            if len(head) < 9:
                scan.cut(True, pos)
                break
            op = head[0]
            if op == 0 or 0x10 <= op < 0x80:
                raise scan.corrupt(f"invalid record opcode 0x{op:02x} at byte {pos}")
            (length,) = struct.unpack_from("<Q", head, 1)
            if pos + 9 + length > size:
                scan.cut(True, pos)
                break
            if op in _OP_DATA_OVER:
                scan.complete = True
                break
            scan.record(op, memoryview(handle.read(length)))
            pos += 9 + length
            pending += length
            if pending >= batch_bytes:
                yield _take(scan)
                pending = 0
    if strict and not scan.complete:
        raise CorruptBagError(f"{file}: truncated MCAP storage (no data end record)")
    yield _take(scan)


def _take(scan: _Scan) -> dict[str, RawTopic]:
    """Return the messages the scan holds and empty it (its channels stay known)."""
    batch = {}
    for topic, raw in scan.topics.items():
        if raw.stamps:
            batch[topic] = RawTopic(raw.type_name, raw.definition, raw.stamps, raw.payloads)
            scan.topics[topic] = RawTopic(raw.type_name, raw.definition)
    return batch


#: This storage for the bag reader's table.
FORMAT: Final = StorageFormat(suffix=".mcap", magic=MAGIC, read=read)
