"""Where the measured data come from: a recording the calibration reads in two ways.

The calibration needs every sample of every actuator only in two forms, never the whole
record at full rate:

- the full-rate series of a few actuators (the screening block of search/state.py, whose fits,
  search and residual analysis run at full rate): :meth:`Recording.block`, and the
  temperature of the whole grid (at the sensor rate): :meth:`Recording.temperature`;
- the whole grid at the samples the grid-wide refit uses (a bounded number per actuator,
  search/state.py's budgets), the commands those samples need, and the play operators of the
  command: :func:`gather`, one pass over :meth:`Recording.batches` that writes each batch's
  rows to the tiles' files (tilestore.py).

So memory is bounded by the block, the temperature, one batch and one tile, not by the
record's length nor by the grid's rows. :class:`MemoryRecording` wraps data already in
memory (the in-memory path, the same code); :class:`.bagstream.BagRecording` streams bags.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Final, Protocol

import numpy as np

from es_calibration.data.align import MeasuredData
from es_calibration.data.edges import EdgeMask, EdgeStream
from es_calibration.errors import RecordingError
from es_calibration.grid.tilestore import TileStore, play_name
from es_calibration.model.composite import play_operator
from es_common.arrays import FloatArray, IndexArray, IntArray

#: Role names of :meth:`Recording.batches`.
COMMAND_ROLE: Final = "command"
DISPLACEMENT_ROLE: Final = "displacement"
#: Store array of whether each gathered command was finite.
COMMAND_FINITE: Final = "command_finite"
#: Rows per batch of :class:`MemoryRecording`.
MEMORY_BATCH_ROWS: Final = 4096


class Recording(Protocol):
    """A measured run that the calibration reads block-wise and in one streamed pass."""

    @property
    def grid(self) -> tuple[int, int]:
        """Return the actuator grid (rows, cols)."""
        ...

    def block(self, columns: IndexArray, shape: tuple[int, int]) -> MeasuredData:
        """Return the full-rate, stamp-sorted data of actuators ``columns`` as a ``shape`` grid."""
        ...

    def temperature(self) -> tuple[FloatArray, FloatArray]:
        """Return the stamp-sorted temperature stamps (Nt,) [s] and values (Nt, A) [degC]."""
        ...

    def batches(self) -> Iterator[tuple[str, IndexArray, FloatArray]]:
        """Yield (role, stamp-sorted message indices, values (n, A)) over the whole run.

        Roles are ``COMMAND_ROLE`` and ``DISPLACEMENT_ROLE``; indices count messages in
        stamp order (equal stamps in recording order). Batches may come in any order, but
        each index exactly once.
        """
        ...


@dataclass(frozen=True)
class Gathered:
    """What :func:`gather` counted (A actuators, row-major); the arrays are in the store.

    Attributes:
        usable: (A,) finite displacements among the kept samples, per actuator.
        displacement_nan: NaN displacements among the kept samples.
        command_nan: NaN command values in the whole run.
        edges: every actuator's command edges, with the delay search's window (None: not
            looked for).

    """

    usable: IntArray
    displacement_nan: int
    command_nan: int
    edges: EdgeMask | None = None


def _runs(positions: IndexArray) -> Iterator[tuple[int, int]]:
    """Yield (start, stop) of the runs of consecutive values in ascending ``positions``."""
    breaks = np.flatnonzero(np.diff(positions) != 1) + 1
    for lo, hi in zip(np.r_[0, breaks], np.r_[breaks, positions.size], strict=True):
        yield int(lo), int(hi)


class _CommandStream:
    """Commands in stamp order (batches reordered), NaN held, with their play operators."""

    def __init__(self, wanted: IndexArray, thresholds: Sequence[float], width: int,
                 store: TileStore, edges: EdgeStream | None) -> None:
        self.wanted = wanted
        self.edges = edges
        self.r = np.asarray(thresholds, np.float64)[:, None]
        self.held = np.zeros(width)
        self.state: FloatArray | None = None
        self.next = 0
        self.pending: list[tuple[IndexArray, FloatArray]] = []
        self.store = store
        self.nan = 0

    def feed(self, index: IndexArray, values: FloatArray) -> None:
        self.pending.append((index, values))
        index = np.concatenate([i for i, _ in self.pending])
        if index.min() > self.next:
            return
        values = np.concatenate([v for _, v in self.pending])
        order = np.argsort(index, kind="stable")
        index, values = index[order], values[order]
        run = int(np.searchsorted(index - np.arange(index.size), self.next, side="right"))
        self.pending = [(index[run:], values[run:])] if run < index.size else []
        if run:
            self._consume(index[:run], values[:run])

    def _consume(self, index: IndexArray, values: FloatArray) -> None:
        """Process the next commands in order (``index`` is consecutive from ``self.next``)."""
        finite = np.isfinite(values)
        bad = int((~finite).sum())
        self.nan += bad
        held = values
        if bad:
            last = np.where(finite, np.arange(index.size)[:, None], -1)
            np.maximum.accumulate(last, axis=0, out=last)
            held = np.where(
                last >= 0, values[np.maximum(last, 0), np.arange(values.shape[1])], self.held
            )
        self.held = held[-1].copy()
        if self.edges is not None:
            self.edges.feed(held)
        lo, hi = np.searchsorted(self.wanted, [index[0], index[-1] + 1])
        local = self.wanted[lo:hi] - index[0]
        if hi > lo:
            self.store.put(COMMAND_ROLE, int(lo), held[local])
            self.store.put(COMMAND_FINITE, int(lo), finite[local])
        if self.r.size:
            keep = np.append(local, index.size - 1)
            out = play_operator(held, self.r, keep, self.state)
            for k in range(self.r.shape[0]):
                if hi > lo:
                    self.store.put(play_name(k), int(lo), out[:-1, k])
            self.state = out[-1]
        self.next = int(index[-1]) + 1


def gather_arrays(samples: int, commands: int, thresholds: int) -> dict[str, tuple[int, str]]:
    """Return the store arrays :func:`gather` fills: name -> (rows, dtype)."""
    arrays = {
        DISPLACEMENT_ROLE: (samples, "float64"),
        COMMAND_ROLE: (commands, "float64"),
        COMMAND_FINITE: (commands, "bool"),
    }
    arrays.update({play_name(k): (commands, "float64") for k in range(thresholds)})
    return arrays


def gather(
    recording: Recording,
    samples: IndexArray,
    kept: IndexArray,
    commands: IndexArray,
    thresholds: Sequence[float],
    *,
    store: TileStore,
    command_times: FloatArray | None = None,
) -> Gathered:
    """Write the whole grid at some samples to ``store``'s tiles in one pass over the recording.

    Written (:func:`gather_arrays`): ``displacement`` (n, A) [m] at ``samples``;
    ``command`` (m, A) [V] at ``commands``, NaN held from the last finite value (0 before
    the first), as align.py holds it, and ``command_finite`` (m, A) whether it was finite;
    ``play<k>`` (m, A) the play operator of the held command for ``thresholds[k]``.

    Args:
        recording: the run.
        samples: stamp-sorted displacement indices to keep (ascending, unique).
        kept: every displacement index the alignment kept (for the usable counts).
        commands: stamp-sorted command indices to keep (ascending, unique).
        thresholds: play thresholds [V] whose operators are wanted at ``commands``.
        store: where the rows go (made with at least :func:`gather_arrays`).
        command_times: every command's stamp [s] in stamp order: each actuator's command
            edges are looked for too (edges.py, on the held command), on this time base.

    Raises:
        RecordingError: the recording's batches left a command out, or ``command_times``
            has not one stamp per command.

    """
    A = recording.grid[0] * recording.grid[1]
    edges = None if command_times is None else EdgeStream(command_times, A)
    stream = _CommandStream(commands, thresholds, A, store, edges)
    usable = np.zeros(A, dtype=np.int64)
    kept_sorted = np.sort(kept)
    for role, index, values in recording.batches():
        if role == COMMAND_ROLE:
            stream.feed(index, values)
            continue
        pos = np.searchsorted(samples, index)
        hit = pos < samples.size
        hit[hit] = samples[pos[hit]] == index[hit]
        if hit.any():
            order = np.argsort(pos[hit], kind="stable")
            found, rows = pos[hit][order], values[hit][order]
            for lo, hi in _runs(found):
                store.put(DISPLACEMENT_ROLE, int(found[lo]), rows[lo:hi])
        k = np.searchsorted(kept_sorted, index)
        in_kept = k < kept_sorted.size
        in_kept[in_kept] = kept_sorted[k[in_kept]] == index[in_kept]
        usable += np.isfinite(values[in_kept]).sum(axis=0)
    if stream.pending:
        raise RecordingError("the recording's command batches skipped an index")
    if command_times is not None and stream.next != command_times.size:
        raise RecordingError(f"the recording has {stream.next} commands, its time base "
                             f"{command_times.size} command stamps")
    return Gathered(
        usable=usable,
        displacement_nan=int(kept.size * A - usable.sum()),
        command_nan=stream.nan,
        edges=None if edges is None else edges.mask(),
    )


class MemoryRecording:
    """A :class:`Recording` over :class:`MeasuredData` already in memory (stamp-sorted)."""

    def __init__(self, data: MeasuredData) -> None:
        """Wrap ``data`` (series sorted by stamp, as the bag readers return them)."""
        self.data = data

    @property
    def grid(self) -> tuple[int, int]:
        """Return the actuator grid (rows, cols)."""
        shape = self.data.displacement.shape
        return (int(shape[1]), int(shape[2])) if len(shape) == 3 else (0, 0)

    def block(self, columns: IndexArray, shape: tuple[int, int]) -> MeasuredData:
        """Return the data of actuators ``columns`` (all of it when they are the grid)."""
        d = self.data
        if shape == self.grid or d.displacement.ndim != 3:
            return d

        def cut(values: FloatArray) -> FloatArray:
            return values.reshape(values.shape[0], -1)[:, columns].reshape(-1, *shape)

        return MeasuredData(
            d.command_times,
            cut(d.command),
            d.displacement_times,
            cut(d.displacement),
            d.temperature_times,
            cut(d.temperature),
            d.temperature_source,
        )

    def temperature(self) -> tuple[FloatArray, FloatArray]:
        """Return the temperature stamps and values (Nt, A)."""
        values = self.data.temperature
        return self.data.temperature_times, values.reshape(values.shape[0], -1)

    def batches(self) -> Iterator[tuple[str, IndexArray, FloatArray]]:
        """Yield the commands, then the displacements, in blocks of rows."""
        for role, values in (
            (COMMAND_ROLE, self.data.command),
            (DISPLACEMENT_ROLE, self.data.displacement),
        ):
            flat = values.reshape(values.shape[0], -1)
            for start in range(0, flat.shape[0], MEMORY_BATCH_ROWS):
                stop = min(start + MEMORY_BATCH_ROWS, flat.shape[0])
                yield role, np.arange(start, stop), flat[start:stop]
