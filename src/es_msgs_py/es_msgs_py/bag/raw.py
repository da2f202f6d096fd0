"""What a storage reader hands to :func:`es_msgs_py.bag.read_bag`: raw topics.

A storage module (``storage_mcap``, ``storage_sqlite3``) reads one storage file into
``{topic: RawTopic}`` (undecoded CDR payloads with their bag stamps); the reader merges the
files of a bag and decodes. Each storage module describes itself with a :class:`StorageFormat`
(file suffix, magic bytes, reader), which the bag reader's table looks up by storage id.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeAlias

__all__ = ["RawTopic", "StorageFormat", "StorageReader"]


@dataclass
class RawTopic:
    """One topic of one storage file, undecoded.

    ``definition`` is the message definition stored in the bag as (encoding, text), e.g.
    ``("ros2msg", "...")``, or ``None``; ``stamps`` are bag timestamps in ns and
    ``payloads`` the CDR messages, in file order.
    """

    type_name: str
    definition: tuple[str, str] | None
    stamps: list[int] = field(default_factory=list)
    payloads: list[memoryview | bytes] = field(default_factory=list)


#: ``read(file, strict, wanted) -> {topic: RawTopic}``. ``strict`` (the bag has
#: ``metadata.yaml``, so it was closed cleanly) makes a truncated file an error; otherwise
#: the file is read up to its last complete record. ``wanted`` limits the topics (None: all).
StorageReader: TypeAlias = Callable[[Path, bool, set[str] | None], dict[str, RawTopic]]


@dataclass(frozen=True)
class StorageFormat:
    """One rosbag2 storage format as the reader needs it.

    ``suffix`` is the storage file's suffix (``".mcap"``), ``magic`` the bytes every such
    file starts with, ``read`` its :data:`StorageReader`.
    """

    suffix: str
    magic: bytes
    read: StorageReader
