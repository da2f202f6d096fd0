"""Read a bag in batches of messages, in file order, so memory does not grow with the bag.

:func:`iter_bag` is the streaming counterpart of :func:`es_msgs_py.bag.read_bag`: the same
storage files (MCAP or sqlite3, split bags, a killed writer's bag), read by the storage
modules' ``iter_read``. Each batch is ``{topic: RawTopic}`` with undecoded CDR payloads in
file order (not sorted by stamp: a reader that needs stamp order sorts the stamps it kept);
decode array topics with :func:`~es_msgs_py.bag.codec.decode_float64_multi_arrays`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Final

from es_msgs_py.bag import storage_mcap, storage_sqlite3
from es_msgs_py.bag.errors import CorruptBagError, NotABagError
from es_msgs_py.bag.raw import RawTopic
from es_msgs_py.bag.reader import storage_files

__all__ = ["BATCH_BYTES", "iter_bag"]

#: Default payload bytes per batch.
BATCH_BYTES: Final = 32 << 20

_IterRead = Callable[[Path, bool, "set[str] | None", int], Iterator[dict[str, RawTopic]]]
#: magic bytes -> streaming storage reader.
_STREAMING: Final[Mapping[bytes, _IterRead]] = MappingProxyType(
    {storage_mcap.MAGIC: storage_mcap.iter_read, storage_sqlite3.MAGIC: storage_sqlite3.iter_read}
)


def iter_bag(
    path: str | Path, topics: Iterable[str] | None = None, batch_bytes: int = BATCH_BYTES
) -> Iterator[dict[str, RawTopic]]:
    """Yield the messages of a bag in batches of about ``batch_bytes`` payload bytes.

    Args:
        path: the bag directory.
        topics: the topics to read; ``None`` reads every topic.
        batch_bytes: payload bytes per batch (a batch holds at least one storage chunk).

    Yields:
        ``{topic: RawTopic}`` of the messages read since the previous batch, in file order.

    Raises:
        BagNotFoundError, NotABagError, CorruptBagError, UnsupportedBagError: as
        :func:`~es_msgs_py.bag.read_bag` (all :class:`~es_msgs_py.errors.BagError`); also a
        topic whose type differs between the files of a split bag.

    """
    wanted = set(topics) if topics is not None else None
    files, strict = storage_files(Path(path))
    types: dict[str, str] = {}
    for file in files:
        with file.open("rb") as handle:
            head = handle.read(max(len(m) for m in _STREAMING))
        reader = next((r for magic, r in _STREAMING.items() if head.startswith(magic)), None)
        if reader is None:
            if not head:
                raise NotABagError(f"{file} is empty")
            raise NotABagError(f"not a bag: {file} is neither MCAP nor sqlite3")
        for batch in reader(file, strict, wanted, batch_bytes):
            for topic, raw in batch.items():
                known = types.setdefault(topic, raw.type_name)
                if known != raw.type_name:
                    raise CorruptBagError(
                        f"{topic} is {known} in one file, {raw.type_name} in {file}"
                    )
            if batch:
                yield batch
