"""Write rosbag2 bags (MCAP or sqlite3) through rosbags' :class:`~rosbags.rosbag2.Writer`.

:class:`BagWriter` takes rclpy messages or CDR bytes; :func:`write_array_bag` writes contract
arrays with numpy alone (test data, tools). :meth:`BagWriter.flush` keeps a bag readable if
its process is killed: the storage file then holds everything written up to the last flush.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Final, Literal, Self

import numpy as np
import numpy.typing as npt
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
from rosbags.typesys import Stores, get_typestore

from es_msgs_py.bag import storage_mcap, storage_sqlite3
from es_msgs_py.bag.codec import FLOAT64_MULTI_ARRAY, encode_float64_multi_array
from es_msgs_py.bag.errors import (
    BagExistsError,
    BagLayoutError,
    BagWriteError,
    UnknownMessageTypeError,
)
from es_msgs_py.topic_names import DM_DEPTH

__all__ = ["BAG_VERSION", "STORAGES", "BagWriter", "Storage", "ros_type_name", "write_array_bag"]

#: rosbag2 metadata version of ROS 2 Jazzy.
BAG_VERSION: Final = 9
#: Storage id (as in ``metadata.yaml``'s ``storage_identifier``) -> rosbags storage plugin.
_PLUGINS: Final = {
    storage_mcap.STORAGE_ID: StoragePlugin.MCAP,
    storage_sqlite3.STORAGE_ID: StoragePlugin.SQLITE3,
}
#: The storages a bag can be written in; the first is the default.
STORAGES: Final = tuple(_PLUGINS)
Storage = Literal["mcap", "sqlite3"]


def _default_qos() -> list[Qos]:
    """Return the offered QoS of a /dm topic: what every es_dm endpoint uses (``DM_QOS``)."""
    never = QosTime(sec=0, nsec=0)
    return [
        Qos(
            QosHistory.KEEP_LAST,
            DM_DEPTH,
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
    """Return the ROS 2 type name (``pkg/msg/Name``) of an rclpy message instance.

    Raises:
        BagWriteError: ``msg`` is not an instance of a generated rclpy message class.

    """
    module = type(msg).__module__.split(".")
    if len(module) < 2 or module[1] != "msg":
        raise BagWriteError(f"not an rclpy message: {type(msg).__name__}")
    return f"{module[0]}/msg/{type(msg).__name__}"


def _flush_storage(writer: Writer) -> None:
    """Make what ``writer`` has written durable in its storage file.

    rosbags' ``Writer`` has no public flush: its storage writers only offer add/write/close
    (the ``StorageWriter`` protocol), and their buffered data reaches the file on close. A
    recorder that is killed must still leave a readable bag, so this one function uses the
    storage writers' own attributes (rosbags 0.11.9): MCAP closes its pending chunk and
    flushes its file, sqlite3 commits its open transaction.
    """
    storage = writer.storage
    if storage is None:
        return
    bio = getattr(storage, "bio", None)
    if bio is not None:
        if storage.chunk.bio.tell():  # type: ignore[attr-defined]
            storage.close_chunk()  # type: ignore[attr-defined]
        bio.flush()
    else:
        storage.conn.commit()  # type: ignore[attr-defined]


class BagWriter:
    """Write a rosbag2 bag: MCAP (default) or sqlite3 storage.

    ``write(topic, t_ns, msg)`` takes an rclpy message, or CDR bytes with ``type_name``.
    Topics are registered on first use (or with :meth:`add_topic`, to give their QoS).
    :meth:`flush` makes everything written so far durable in the storage file, so a bag
    whose process is killed stays readable up to the last flush; :meth:`close` finishes the
    storage and writes ``metadata.yaml``.
    """

    def __init__(self, path: str | Path, storage: Storage | str = "mcap") -> None:
        """Create the bag directory ``path`` (which must not exist) and open its storage.

        Raises:
            BagWriteError: ``storage`` is not one of :data:`STORAGES`, or the bag cannot be
                created.
            BagExistsError: ``path`` exists already.

        """
        if storage not in _PLUGINS:
            raise BagWriteError(f"storage must be one of {list(STORAGES)}, got {storage!r}")
        self.path = Path(path)
        self.storage: str = storage
        if self.path.exists():
            raise BagExistsError(f"{self.path} exists already; a bag is never overwritten")
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=_PLUGINS[storage])
        self._typestore = get_typestore(Stores.ROS2_JAZZY)
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}
        try:
            self._writer.open()
        except (WriterError, OSError) as err:
            raise BagWriteError(f"cannot create bag {self.path}: {err}") from None
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
            UnknownMessageTypeError: the type is not a ROS 2 Jazzy type.
            BagWriteError: the topic was registered with another type.

        """
        known = self._connections.get(topic)
        if known is not None:
            if known.msgtype != type_name:
                raise BagWriteError(f"{topic} is {known.msgtype} in this bag, not {type_name}")
            return
        if type_name not in self._typestore.fielddefs:
            raise UnknownMessageTypeError(f"unknown message type {type_name!r} for topic {topic}")
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

        Raises:
            BagWriteError: the bag is closed, bytes come without ``type_name``, ``msg`` is
                no rclpy message, or the topic has another type in this bag.
            UnknownMessageTypeError: the type is not a ROS 2 Jazzy type.

        """
        if not self._open:
            raise BagWriteError(f"bag {self.path} is closed")
        if isinstance(msg, bytes | bytearray | memoryview):
            if type_name is None:
                raise BagWriteError(f"{topic}: type_name is required for serialized data")
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
        transaction is committed.
        """
        _flush_storage(self._writer)

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

    Raises:
        BagLayoutError: times are not 1-D or values not (N, R, C) / (N, S) for N times.
        BagWriteError: the bag cannot be created (see :class:`BagWriter`).
        BagExistsError: ``path`` exists already.

    """
    checked = []
    for topic, (times, values) in series.items():
        t_ns = np.round(np.asarray(times, dtype=np.float64) * 1e9).astype(np.int64)
        arr = np.asarray(values, dtype=np.float64)
        if t_ns.ndim != 1 or arr.ndim not in (2, 3) or len(arr) != len(t_ns):
            raise BagLayoutError(
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
