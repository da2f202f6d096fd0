"""Read a rosbag2 bag (MCAP or sqlite3) into one :class:`TopicSeries` per topic.

Each contract array topic (``std_msgs/msg/Float64MultiArray``) becomes one float64 array,
(N, R, C) for grids and (N, S) for sensor vectors (:mod:`es_msgs_py.bag.codec`). Other types
come back as messages deserialized by a rosbags typestore (ROS 2 Jazzy types, plus types
whose definition the bag carries).

The storage files are read by the storage modules in :data:`STORAGE_PLUGINS`, keyed by
rosbag2 storage id; a file's id is recognised from its magic bytes. A bag *with*
``metadata.yaml`` was closed cleanly, so a truncated or damaged storage file is an error. A
bag whose writer died (SIGKILL, power loss) has no ``metadata.yaml``; it is read from its
storage alone, up to the last complete record.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import yaml
from rosbags.typesys import (
    Stores,
    TypesysError,
    get_types_from_idl,
    get_types_from_msg,
    get_typestore,
)

from es_msgs_py.bag import storage_mcap, storage_sqlite3
from es_msgs_py.bag.codec import FLOAT64_MULTI_ARRAY, FloatArray, decode_float64_multi_arrays
from es_msgs_py.bag.errors import (
    BagNotFoundError,
    CorruptBagError,
    MissingTopicError,
    NotABagError,
    UnknownMessageTypeError,
    UnsupportedBagError,
)
from es_msgs_py.bag.raw import RawTopic, StorageFormat

if TYPE_CHECKING:  # the class get_typestore returns, named for annotations only
    from rosbags.typesys.store import Typestore

__all__ = ["STORAGE_PLUGINS", "TopicSeries", "read_bag", "storage_files"]

#: rosbag2 storage id -> how to recognise and read its files.
STORAGE_PLUGINS: Final[Mapping[str, StorageFormat]] = MappingProxyType(
    {
        storage_mcap.STORAGE_ID: storage_mcap.FORMAT,
        storage_sqlite3.STORAGE_ID: storage_sqlite3.FORMAT,
    }
)
# The longest magic is read from each file (sqlite3's, 16 bytes).
_HEAD_BYTES: Final = max(len(plugin.magic) for plugin in STORAGE_PLUGINS.values())


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


def storage_files(path: Path) -> tuple[list[Path], bool]:
    """Return the bag's storage files (several for a split bag) and whether it was closed.

    Raises:
        BagNotFoundError: ``path`` does not exist.
        NotABagError: ``path`` is a file, holds no storage, or its metadata is no rosbag2's.
        UnsupportedBagError: the bag is compressed.
        CorruptBagError: a storage file named in ``metadata.yaml`` is missing.

    """
    if not path.exists():
        raise BagNotFoundError(f"bag not found: {path}")
    if path.is_file():
        raise NotABagError(f"{path} is a file; a rosbag2 bag is a directory with metadata.yaml")
    if not (path / "metadata.yaml").is_file():
        suffixes = {plugin.suffix for plugin in STORAGE_PLUGINS.values()}
        files = sorted(p for p in path.iterdir() if p.suffix in suffixes)
        if not files:
            raise NotABagError(f"not a bag: {path} has no metadata.yaml and no .mcap/.db3 file")
        return files, False
    try:
        meta = yaml.safe_load((path / "metadata.yaml").read_text())
        info = meta["rosbag2_bagfile_information"]
        names = [str(n) for n in info["relative_file_paths"]]
    except (yaml.YAMLError, KeyError, TypeError, UnicodeDecodeError):
        raise NotABagError(f"{path}/metadata.yaml is not rosbag2 metadata") from None
    if info.get("compression_mode"):
        raise UnsupportedBagError(f"{path}: file- or message-compressed bags are not supported")
    for name in names:
        if not (path / name).is_file():
            raise CorruptBagError(f"{path}: storage file {name} named in metadata.yaml is missing")
    return [path / name for name in names], True


def _read_storage(file: Path, strict: bool, wanted: set[str] | None) -> dict[str, RawTopic]:
    """Read one storage file with the plugin whose magic bytes it starts with.

    Raises:
        NotABagError: the file is empty or of no known storage.
        BagError: what the storage plugin raises.

    """
    with file.open("rb") as handle:
        head = handle.read(_HEAD_BYTES)
    for plugin in STORAGE_PLUGINS.values():
        if head.startswith(plugin.magic):
            return plugin.read(file, strict, wanted)
    if not head:
        raise NotABagError(f"{file} is empty")
    raise NotABagError(f"not a bag: {file} is neither MCAP nor sqlite3")


def _register_type(store: Typestore, raw: RawTopic, topic: str) -> None:
    """Make ``raw``'s type known to ``store``, from the definition the bag carries.

    Raises:
        UnknownMessageTypeError: the type is unknown and the bag has no usable definition.

    """
    if raw.type_name in store.fielddefs:
        return
    if raw.definition is None or not raw.definition[1].strip():
        raise UnknownMessageTypeError(
            f"{topic}: unknown message type {raw.type_name!r} (no definition in bag)"
        )
    encoding, text = raw.definition
    try:
        types = (
            get_types_from_idl(text)
            if encoding == "ros2idl"
            else get_types_from_msg(text, raw.type_name)
        )
        store.register(types)
    except TypesysError as err:
        raise UnknownMessageTypeError(
            f"{topic}: unknown message type {raw.type_name!r}: {err}"
        ) from None


def read_bag(path: str | Path, topics: Iterable[str] | None = None) -> dict[str, TopicSeries]:
    """Read a bag (MCAP or sqlite3) into one :class:`TopicSeries` per topic.

    Args:
        path: the bag directory.
        topics: the topics to read; ``None`` reads every topic of the bag.

    Returns:
        ``{topic: TopicSeries}``, topics sorted by name, messages sorted by bag time.

    Raises:
        BagNotFoundError: the path does not exist.
        NotABagError: the path is not a bag (a file, no storage, foreign or empty files).
        CorruptBagError: its storage is corrupt or (for a cleanly closed bag) truncated.
        UnsupportedBagError: it is compressed.
        MissingTopicError: a requested topic is missing.
        UnknownMessageTypeError: a message type is unknown.
        BagLayoutError: an array topic breaks the contract layout or changes shape.

    All of these are :class:`~es_msgs_py.errors.BagError`.

    """
    bag = Path(path)
    wanted = set(topics) if topics is not None else None
    files, strict = storage_files(bag)
    raw_topics: dict[str, RawTopic] = {}
    for file in files:
        for topic, raw in _read_storage(file, strict, wanted).items():
            known = raw_topics.setdefault(topic, raw)
            if known is raw:
                continue
            if known.type_name != raw.type_name:
                raise CorruptBagError(
                    f"{topic} is {known.type_name} in one file, {raw.type_name} in {file}"
                )
            known.stamps.extend(raw.stamps)
            known.payloads.extend(raw.payloads)
    return _to_series(bag, raw_topics, wanted)


def _to_series(
    bag: Path, raw_topics: dict[str, RawTopic], wanted: set[str] | None
) -> dict[str, TopicSeries]:
    """Decode raw topics: arrays with the codec, other types with a rosbags typestore.

    Raises:
        MissingTopicError: a wanted topic is not in ``raw_topics``.
        UnknownMessageTypeError: a type is unknown (see :func:`_register_type`).
        CorruptBagError: a message cannot be deserialized.
        BagLayoutError: an array topic breaks the contract layout or changes shape.

    """
    if wanted is not None:
        missing = sorted(wanted - raw_topics.keys())
        if missing:
            raise MissingTopicError(
                f"{bag}: topic(s) {', '.join(missing)} not in bag "
                f"(has: {', '.join(sorted(raw_topics)) or 'nothing'})"
            )
    store = get_typestore(Stores.ROS2_JAZZY)
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
                raise CorruptBagError(f"{topic}: corrupt {raw.type_name} message ({err})") from None
        result[topic] = series
    return result
