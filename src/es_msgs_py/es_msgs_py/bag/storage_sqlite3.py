"""Read the sqlite3 storage of a rosbag2 bag (``.db3``) with the standard library."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Final

from es_msgs_py.bag.errors import CorruptBagError, NotABagError
from es_msgs_py.bag.raw import RawTopic, StorageFormat

__all__ = ["FORMAT", "MAGIC", "STORAGE_ID", "iter_read", "read"]

#: rosbag2's storage identifier.
STORAGE_ID: Final = "sqlite3"
#: The first bytes of every sqlite3 database file.
MAGIC: Final = b"SQLite format 3\x00"


def read(file: Path, strict: bool, wanted: set[str] | None) -> dict[str, RawTopic]:
    """Return the topics of an sqlite3 storage file (see :data:`~es_msgs_py.bag.raw.StorageReader`).

    Without ``strict`` the database is opened read-write: a killed writer leaves a hot
    journal that sqlite rolls back, which leaves every committed (flushed) message.

    Raises:
        NotABagError: the file is not an sqlite3 database.
        CorruptBagError: the database is damaged, or (``strict``) was never closed.

    """
    topics: dict[str, RawTopic] = {}
    try:
        with file.open("rb") as handle:
            if handle.read(16) != MAGIC:
                raise NotABagError(f"{file} is not an sqlite3 bag (bad file header)")
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
                    topics[name] = RawTopic(type_name, definitions.get(type_name))
            tables = {row[0] for row in conn.execute("SELECT name FROM sqlite_master")}
            # Jazzy writes a metadata row on close; older distributions have no such table.
            closed = (
                "metadata" not in tables
                or conn.execute("SELECT count(*) FROM metadata").fetchone()[0]
            )
            if strict and not closed:
                raise CorruptBagError(f"{file}: truncated sqlite3 storage (it was never closed)")
            rows = conn.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id")
            for topic_id, stamp, data in rows:
                name = ids.get(topic_id)
                if name is not None:
                    topics[name].stamps.append(stamp)
                    topics[name].payloads.append(data)
        finally:
            conn.close()
    except sqlite3.DatabaseError as err:
        raise CorruptBagError(f"{file}: corrupt sqlite3 bag ({err})") from None
    return topics


def iter_read(
    file: Path, strict: bool, wanted: set[str] | None, batch_bytes: int
) -> Iterator[dict[str, RawTopic]]:
    """Yield the topics of an sqlite3 storage file in batches of about ``batch_bytes``.

    Messages come in insertion (file) order, fetched in blocks, so memory does not grow
    with the file; topics without messages in a batch are left out.

    Raises:
        NotABagError: the file is not an sqlite3 database.
        CorruptBagError: the database is damaged, or (``strict``) was never closed.

    """
    try:
        with file.open("rb") as handle:
            if handle.read(16) != MAGIC:
                raise NotABagError(f"{file} is not an sqlite3 bag (bad file header)")
        conn = sqlite3.connect(f"file:{file}?mode={'ro' if strict else 'rw'}", uri=True)
        try:
            definitions = {
                row[0]: (row[1], row[2])
                for row in conn.execute(
                    "SELECT topic_type, encoding, encoded_message_definition "
                    "FROM message_definitions"
                )
            }
            ids: dict[int, tuple[str, str]] = {}
            for topic_id, name, type_name in conn.execute("SELECT id, name, type FROM topics"):
                if wanted is None or name in wanted:
                    ids[topic_id] = (name, type_name)
            tables = {row[0] for row in conn.execute("SELECT name FROM sqlite_master")}
            closed = (
                "metadata" not in tables
                or conn.execute("SELECT count(*) FROM metadata").fetchone()[0]
            )
            if strict and not closed:
                raise CorruptBagError(f"{file}: truncated sqlite3 storage (it was never closed)")
            rows = conn.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id")
            batch: dict[str, RawTopic] = {}
            pending = 0
            while block := rows.fetchmany(256):
                for topic_id, stamp, data in block:
                    known = ids.get(topic_id)
                    if known is None:
                        continue
                    raw = batch.get(known[0])
                    if raw is None:
                        raw = batch[known[0]] = RawTopic(known[1], definitions.get(known[1]))
                    raw.stamps.append(stamp)
                    raw.payloads.append(data)
                    pending += len(data)
                if pending >= batch_bytes:
                    yield batch
                    batch, pending = {}, 0
            yield batch
        finally:
            conn.close()
    except sqlite3.DatabaseError as err:
        raise CorruptBagError(f"{file}: corrupt sqlite3 bag ({err})") from None


#: This storage for the bag reader's table.
FORMAT: Final = StorageFormat(suffix=".db3", magic=MAGIC, read=read)
