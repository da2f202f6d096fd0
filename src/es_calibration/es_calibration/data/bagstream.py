"""Measured-data bags as a streamed :class:`~es_calibration.data.recording.Recording`.

:class:`BagRecording` reads each bag twice in batches of messages (es_msgs_py.bag.stream),
never holding a whole grid topic:

1. on opening: every stamp, the temperature of the whole grid (at its sensor rate) and the
   full-rate command and displacement of the screening block (search/state.py) only;
2. :meth:`BagRecording.batches`: command and displacement batches for one gathering pass.

Every problem with a bag is one :class:`CalibrationInputError` with one readable line
(the checks shared with :mod:`.bags`). Messages are numbered in stamp order (equal stamps in file
order), several bags one after the other in start-time order.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path

import numpy as np

from es_calibration.data.align import (
    COMMAND,
    DISPLACEMENT,
    TEMPERATURE,
    TEMPERATURE_RAW,
    CalibrationInputError,
    MeasuredData,
)
from es_calibration.data.bags import check_bag_list, listed_topics, on_grid
from es_calibration.data.recording import COMMAND_ROLE, DISPLACEMENT_ROLE, RecordingError
from es_calibration.search.state import screen_block
from es_common.arrays import FloatArray, IndexArray
from es_msgs_py.bag import FLOAT64_MULTI_ARRAY, BagError, decode_float64_multi_arrays
from es_msgs_py.bag.stream import BATCH_BYTES, iter_bag

_GRID_TOPICS = (COMMAND, DISPLACEMENT)
_ROLES = {COMMAND: COMMAND_ROLE, DISPLACEMENT: DISPLACEMENT_ROLE}


@dataclass
class _Topic:
    """One topic of one bag as the first pass keeps it (file order until sorted)."""

    stamps: list[np.ndarray] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)
    shape: tuple[int, ...] | None = None
    times: FloatArray = field(default_factory=lambda: np.zeros(0))
    kept: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    rank: IndexArray = field(default_factory=lambda: np.zeros(0, np.intp))

    def add(self, topic: str, stamps: list[int], values: np.ndarray, path: Path) -> None:
        if self.shape is None:
            self.shape = values.shape[1:]
        elif values.shape[1:] != self.shape:
            raise CalibrationInputError(
                f"{path}: {topic}: inconsistent array shapes in one topic: {self.shape} and "
                f"{values.shape[1:]}"
            )
        self.stamps.append(np.asarray(stamps, np.int64))
        self.values.append(values)

    def finish(self) -> None:
        """Sort by stamp (stable) and remember each file position's sorted index."""
        stamps = np.concatenate(self.stamps) if self.stamps else np.zeros(0, np.int64)
        order = np.argsort(stamps, kind="stable")
        self.times = stamps[order].astype(np.float64) * 1e-9
        if self.values:
            self.kept = np.concatenate(self.values)[order]
        self.rank = np.empty(order.size, np.intp)
        self.rank[order] = np.arange(order.size)
        self.stamps, self.values = [], []


class _Bag:
    """First pass over one bag (see the module docstring)."""

    def __init__(self, path: Path, batch_bytes: int) -> None:
        self.path = path
        listed = listed_topics(path)
        wanted = [COMMAND, DISPLACEMENT, TEMPERATURE, TEMPERATURE_RAW]
        if listed is not None:
            wanted = [t for t in wanted if t in listed]
        self.topics = {t: _Topic() for t in wanted}
        self.grids: dict[str, tuple[int, int]] = {}
        try:
            for batch in iter_bag(path, wanted, batch_bytes):
                for topic, raw in batch.items():
                    self._add(topic, raw.type_name, raw.stamps, raw.payloads)
        except BagError as err:
            raise CalibrationInputError(str(err)) from None
        for t in self.topics.values():
            t.finish()
        self._check(listed)

    def _add(self, topic: str, type_name: str, stamps: list[int], payloads: list) -> None:
        if type_name != FLOAT64_MULTI_ARRAY:
            what = "a row x col grid topic" if topic in _GRID_TOPICS else "a Float64MultiArray"
            raise CalibrationInputError(f"{self.path}: {topic} is not {what}")
        values = decode_float64_multi_arrays(topic, payloads)
        if topic in _GRID_TOPICS:
            if values.ndim != 3:
                raise CalibrationInputError(f"{self.path}: {topic} is not a row x col grid topic")
            grid = (int(values.shape[1]), int(values.shape[2]))
            if self.grids.setdefault(topic, grid) != grid:
                raise CalibrationInputError(
                    f"{self.path}: {topic}: inconsistent array shapes in one topic: "
                    f"{self.grids[topic]} and {grid}"
                )
            columns, _ = screen_block(grid)
            values = values.reshape(values.shape[0], -1)[:, columns]
        self.topics[topic].add(topic, stamps, values, self.path)

    def _check(self, listed: set[str] | None) -> None:
        present = {t for t, s in self.topics.items() if s.times.size}
        empty = sorted(set(self.topics) - present)
        missing = [t for t in _GRID_TOPICS if t not in present]
        self.temperature_topic = next(
            (t for t in (TEMPERATURE, TEMPERATURE_RAW) if t in present), None
        )
        if missing or self.temperature_topic is None:
            need = [*missing] + (
                [] if self.temperature_topic else [f"{TEMPERATURE} or {TEMPERATURE_RAW}"]
            )
            raise CalibrationInputError(
                f"{self.path}: bag without data on the needed topics: missing "
                f"{', '.join(need)} (with messages: {', '.join(sorted(present)) or 'none'}; "
                f"empty: {', '.join(empty) or 'none'})"
            )
        self.grid_shape = self.grids[DISPLACEMENT]
        if self.grids[COMMAND] != self.grid_shape:
            c = self.grids[COMMAND]
            raise CalibrationInputError(
                f"{self.path}: mismatched grid sizes: {COMMAND} is {c[0]} x {c[1]}, "
                f"{DISPLACEMENT} is {self.grid_shape[0]} x {self.grid_shape[1]}"
            )
        temp = self.topics[self.temperature_topic]
        temp.kept = on_grid(temp.kept, self.grid_shape, self.path).reshape(temp.times.size, -1)


class BagRecording:
    """Measured-data bags of one mirror, streamed (see the module docstring)."""

    def __init__(self, paths: Sequence[str | Path], batch_bytes: int = BATCH_BYTES) -> None:
        """Read every bag's stamps, temperature and screening block (the first pass).

        Raises:
            CalibrationInputError: no bag, a bag given twice, unreadable, without the needed
                topics, bags overlapping in time or disagreeing on grid or temperature topic
                (one readable line).

        """
        check_bag_list(paths)
        self.batch_bytes = batch_bytes
        bags = sorted((_Bag(Path(p), batch_bytes) for p in paths),
                      key=lambda b: b.topics[DISPLACEMENT].times[0])
        for a, b in pairwise(bags):
            if b.topics[DISPLACEMENT].times[0] <= a.topics[DISPLACEMENT].times[-1]:
                raise CalibrationInputError(
                    f"bags {a.path} and {b.path} overlap in time: give bags of one mirror "
                    "recorded one after the other"
                )
        if len({b.grid_shape for b in bags}) > 1:
            raise CalibrationInputError(
                f"mismatched grid sizes between bags: {sorted({b.grid_shape for b in bags})}"
            )
        if len({b.temperature_topic for b in bags}) > 1:
            raise CalibrationInputError("bags disagree on the temperature topic")
        self.bags = bags
        self._grid = bags[0].grid_shape

    @property
    def grid(self) -> tuple[int, int]:
        """Return the actuator grid (rows, cols)."""
        return self._grid

    def _cat(self, topic: str | None, what: str) -> np.ndarray:
        parts = [getattr(b.topics[topic or str(b.temperature_topic)], what) for b in self.bags]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)  # no copy of one bag

    def block(self, columns: IndexArray, shape: tuple[int, int]) -> MeasuredData:
        """Return the screening block's data (the only columns the first pass kept).

        Raises:
            RecordingError: ``columns`` are not the screening block of the grid.

        """
        expected, _ = screen_block(self.grid)
        if not np.array_equal(columns, expected):
            raise RecordingError("a streamed bag keeps only the screening block at full rate")
        temp = self._cat(None, "kept")[:, columns]
        return MeasuredData(
            command_times=self._cat(COMMAND, "times"),
            command=self._cat(COMMAND, "kept").reshape(-1, *shape),
            displacement_times=self._cat(DISPLACEMENT, "times"),
            displacement=self._cat(DISPLACEMENT, "kept").reshape(-1, *shape),
            temperature_times=self._cat(None, "times"),
            temperature=temp.reshape(-1, *shape),
            temperature_source=str(self.bags[0].temperature_topic),
        )

    def temperature(self) -> tuple[FloatArray, FloatArray]:
        """Return the temperature stamps (Nt,) [s] and values (Nt, A) [degC] of the grid."""
        return self._cat(None, "times"), self._cat(None, "kept")

    def batches(self) -> Iterator[tuple[str, IndexArray, FloatArray]]:
        """Stream command and displacement batches (the second pass), stamp-order indices."""
        offsets = {COMMAND: 0, DISPLACEMENT: 0}
        for bag in self.bags:
            position = {COMMAND: 0, DISPLACEMENT: 0}
            try:
                for batch in iter_bag(bag.path, _GRID_TOPICS, self.batch_bytes):
                    for topic, raw in batch.items():
                        values = decode_float64_multi_arrays(topic, raw.payloads)
                        n = values.shape[0]
                        start = position[topic]
                        index = offsets[topic] + bag.topics[topic].rank[start : start + n]
                        position[topic] = start + n
                        yield _ROLES[topic], index, values.reshape(n, -1)
            except BagError as err:
                raise CalibrationInputError(str(err)) from None
            for topic in _GRID_TOPICS:
                offsets[topic] += bag.topics[topic].times.size
