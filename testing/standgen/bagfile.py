"""Write a :class:`~standgen.stand.Recording` as a rosbag2 bag with the ``rosbags`` library.

std_msgs/msg/Float64MultiArray in the contract's layout (grid: dims ``row`` and ``col``;
sensors: dim ``sensor``), serialised by rosbags' CDR serialiser. Every message of a topic has
the same header and length, so the header is serialised once and each message is that header
followed by its little-endian float64 data; the first message of every topic is checked
against a full ``serialize_cdr`` of the same message. Messages are written in stamp order
across topics, as a recorder receives them. MCAP or sqlite3 storage, rosbag2 version 9
(ROS 2 Jazzy).
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from standgen._typing import FloatArray
from standgen.stand import Recording

FLOAT64_MULTI_ARRAY: Final = "std_msgs/msg/Float64MultiArray"
STORAGES: Final = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
COMMAND: Final = "/dm/command"
DISPLACEMENT: Final = "/dm/displacement"


class StandBagError(ValueError):
    """The bag cannot be written (unknown storage, existing path, serialisation mismatch)."""


class _ArrayEncoder:
    """CDR bytes of Float64MultiArray messages of one fixed layout."""

    def __init__(self, dims: list[tuple[str, int, int]], count: int) -> None:
        self.store = get_typestore(Stores.ROS2_JAZZY)
        self.dims = dims
        self.count = count
        template = self.serialize(np.zeros(count))
        self.header = template[: len(template) - 8 * count]

    def serialize(self, values: FloatArray) -> bytes:
        """Serialise one message with rosbags (the reference encoding)."""
        types = self.store.types
        layout = types["std_msgs/msg/MultiArrayLayout"](
            dim=[types["std_msgs/msg/MultiArrayDimension"](label=label, size=size, stride=stride)
                 for label, size, stride in self.dims],
            data_offset=0,
        )
        msg = types[FLOAT64_MULTI_ARRAY](layout=layout, data=np.ascontiguousarray(values))
        return bytes(self.store.serialize_cdr(msg, FLOAT64_MULTI_ARRAY))

    def encode(self, values: FloatArray) -> bytes:
        """Header + data; equal to :meth:`serialize` (checked on a topic's first message)."""
        return self.header + np.ascontiguousarray(values, "<f8").tobytes()


def _encoder(values: FloatArray) -> _ArrayEncoder:
    if values.ndim == 3:
        rows, cols = values.shape[1:]
        return _ArrayEncoder([("row", rows, rows * cols), ("col", cols, cols)], rows * cols)
    count = values.shape[1]
    return _ArrayEncoder([("sensor", count, count)], count)


def write_bag(recording: Recording, path: str | Path, storage: str = "mcap") -> dict[str, int]:
    """Write /dm/command, /dm/displacement and the temperature topic; return message counts.

    Raises:
        StandBagError: unknown storage, ``path`` exists, or the spliced encoding differs from
            rosbags' own serialisation.

    """
    if storage not in STORAGES:
        raise StandBagError(f"storage must be one of {list(STORAGES)}, not {storage!r}")
    bag_path = Path(path)
    if bag_path.exists():
        raise StandBagError(f"{bag_path} exists already")
    start = recording.config.start_time_s
    topics = [
        (COMMAND, recording.command_times, recording.command),
        (DISPLACEMENT, recording.displacement_times, recording.displacement),
        (recording.temperature_topic, recording.temperature_times, recording.temperature),
    ]
    encoders = [_encoder(values) for _, _, values in topics]
    for encoder, (topic, _, values) in zip(encoders, topics, strict=True):
        flat = values.reshape(values.shape[0], -1)
        if flat.shape[0] and encoder.encode(flat[0]) != encoder.serialize(flat[0]):
            raise StandBagError(f"{topic}: spliced CDR differs from rosbags' serialisation")
    stamps = np.concatenate([np.round((start + times) * 1e9).astype(np.int64)
                             for _, times, _ in topics])
    which = np.concatenate([np.full(times.size, i) for i, (_, times, _) in enumerate(topics)])
    index = np.concatenate([np.arange(times.size) for _, times, _ in topics])
    order = np.lexsort((which, stamps))
    writer = Writer(bag_path, version=9, storage_plugin=STORAGES[storage])
    writer.open()
    try:
        store = encoders[0].store
        connections = [writer.add_connection(topic, FLOAT64_MULTI_ARRAY, typestore=store)
                       for topic, _, _ in topics]
        flats = [values.reshape(values.shape[0], -1) for _, _, values in topics]
        for k in order:
            i = int(which[k])
            writer.write(connections[i], int(stamps[k]), encoders[i].encode(flats[i][index[k]]))
    finally:
        writer.close()
    return {topic: int(times.size) for topic, times, _ in topics}
