"""Command edges the recorded commands cannot resolve, and the samples whose input needs them.

The model reads the command between its stamps (a fractional delay interpolates the
commands around the delayed instant, search/state.py). That reading is good where the drive is
smooth on the scale of a command period, and unknowable where the drive changes faster than
its samples can show (a step, a slewed edge shorter than a period, a kink): the
displacement samples whose model input would be read there cannot be modelled, whatever
the model, and are left out of fit and scoring like the samples a gap takes (gaps.py).

The rule, from the recorded commands only:

- the *departure* of a command interval is how far its slope (step / interval length)
  departs from the slope its two neighbours predict at its midpoint (their linear
  interpolation, exact for a quadratic drive), times the command period [V];
- an interval is an *edge* when, for some actuator, its departure exceeds ``EDGE_RATIO``
  times the smaller of the largest departures among the ``LOCAL_WINDOW`` intervals before
  it and after it (its immediate neighbours left out: an edge moves them too; near an end of
  the record only the side within it counts) and exceeds ``EDGE_FLOOR`` times the command
  range of all the actuators together (round-off, quantisation and a steady actuator's
  read-out noise are never edges). A smooth drive, even a fast tone, has departures that
  vary smoothly, so none
  stands out; a step stands out of a flat or smooth neighbourhood;
- an interval next to a gap (longer than ``GAP_FACTOR`` periods) is never an edge: the
  gap's own exclusion covers it;
- an edge takes out only the samples of the actuators whose own command has it
  (per-actuator masks, :class:`EdgeMask`): independently driven actuators keep their
  samples between their own edges;
- before the delay is known (the delay search), the samples an edge takes are those whose
  input could read the interval at any shift the search considers (delayrange.py), with the
  interpolation's reach of one period and a margin of ``EDGE_MARGIN_PERIODS`` on each side:
  the same samples for every candidate model, so candidates are compared on the same
  samples (:func:`search_window`);
- once the delay d is known, an edge takes only the samples whose delayed instant t - d
  lies within ``REACH_PERIODS`` (the cubic interpolation's taps) plus the margin of the
  interval (:func:`delay_window`): a few periods instead of the whole search span.

The pairs (edge, actuator) are kept sparse (their times and the actuator), and a mask is
made only for the rows and actuators a fit uses, so memory stays bounded on any grid.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Final

import numpy as np
from scipy.ndimage import maximum_filter1d

from es_calibration.data.delayrange import shift_span
from es_calibration.data.gaps import GAP_FACTOR
from es_calibration.errors import RecordingError
from es_common.arrays import BoolArray, FloatArray, IndexArray, IntArray
from es_feedforward.kernels import Backend, default_backend

#: An interval whose departure exceeds this many times its neighbourhood's is an edge.
EDGE_RATIO: Final = 3.0
#: Intervals on each side whose departures make the neighbourhood.
LOCAL_WINDOW: Final = 8
#: Departures below this fraction of the actuators' command range are never edges.
EDGE_FLOOR: Final = 1e-3
#: Margin on each side of an edge's excluded span [command periods].
EDGE_MARGIN_PERIODS: Final = 1.0
#: Reach of the fractional-delay interpolation around the delayed instant [command periods]
#: (the cubic kernel's taps, search/state.py: from 2 - f periods before to 1 + f after it).
REACH_PERIODS: Final = 2.0
#: Edges whose times the report and calibration.json list.
EXAMPLES: Final = 5
#: Actuators whose departures (or masks) are computed at once (bounds the temporaries).
COLUMNS: Final = 16


def search_window(period_s: float) -> tuple[float, float]:
    """Return (before, after) [s] of the samples an edge takes while the delay is unknown.

    A sample at t is taken out when c_i - before <= t <= c_i+1 + after for an edge interval
    (c_i, c_i+1): every shift the delay search reaches, with the reach of one period and
    the margin on each side.
    """
    if period_s <= 0.0:
        return 0.0, 0.0
    lowest, highest = shift_span(period_s)
    return (
        (1.0 + EDGE_MARGIN_PERIODS - lowest) * period_s,
        (1.0 + EDGE_MARGIN_PERIODS + highest) * period_s,
    )


def delay_window(period_s: float, delay_s: float) -> tuple[float, float]:
    """Return (before, after) [s] of the samples an edge takes once the delay is known.

    The samples whose delayed instant t - ``delay_s`` lies within ``REACH_PERIODS`` +
    ``EDGE_MARGIN_PERIODS`` periods of the edge interval.
    """
    reach = (REACH_PERIODS + EDGE_MARGIN_PERIODS) * period_s
    return reach - delay_s, reach + delay_s


@dataclass(frozen=True)
class EdgeMask:
    """Per-actuator edges, sparse: which (sample, actuator) pairs they take out.

    Attributes:
        start_s, end_s: (P,) the stamps of each edge interval [s] (on the aligned time base).
        actuator: (P,) the actuator (grid row-major index) whose command has that edge.
        before_s, after_s: the window taken around an interval [s] (:func:`search_window`
            or :func:`delay_window`).
        delay_s: the delay the window was made for (None: the delay search's window).
        examined: the actuators whose commands were examined (None: all of them); any
            other actuator takes every examined actuator's edges (its own commands were
            never looked at, so any edge may be its own too).
        by_actuator: the pairs are sorted by actuator (a tile's pairs are then found by
            search, not by a pass over every pair of the grid).

    """

    start_s: FloatArray
    end_s: FloatArray
    actuator: IndexArray
    before_s: float
    after_s: float
    delay_s: float | None = None
    examined: IndexArray | None = None
    by_actuator: bool = False

    @classmethod
    def empty(cls) -> EdgeMask:
        """Return a mask that takes nothing out."""
        return cls(np.zeros(0), np.zeros(0), np.zeros(0, np.intp), 0.0, 0.0)

    def with_delay(self, period_s: float, delay_s: float) -> EdgeMask:
        """Return the mask for a known delay ``delay_s`` [s] at command period ``period_s``."""
        before, after = delay_window(period_s, delay_s)
        return replace(self, before_s=before, after_s=after, delay_s=delay_s)

    def shifted(self, offset_s: float) -> EdgeMask:
        """Return the mask on a time base ``offset_s`` [s] later (times minus the offset)."""
        return replace(self, start_s=self.start_s - offset_s, end_s=self.end_s - offset_s)

    def renumbered(self, columns: IndexArray) -> EdgeMask:
        """Return the mask with actuator i renamed ``columns[i]``; only those were examined."""
        return replace(self, actuator=columns[self.actuator], examined=np.sort(columns),
                       by_actuator=False)

    def _pairs_of(self, actuators: IndexArray) -> tuple[IndexArray, IndexArray]:
        """Return (pair, row): the pairs of ``actuators`` and the row of each in them."""
        if self.by_actuator:
            first = np.searchsorted(self.actuator, actuators, side="left")
            count = np.searchsorted(self.actuator, actuators, side="right") - first
            row = np.repeat(np.arange(actuators.size), count)
            offset = np.repeat(first - (np.cumsum(count) - count), count)
            return offset + np.arange(row.size), row
        lookup = np.full(int(max(self.actuator.max(), actuators.max())) + 1, -1, np.intp)
        lookup[actuators] = np.arange(actuators.size)
        own = lookup[self.actuator]
        pair = np.flatnonzero(own >= 0)
        return pair, own[pair]

    def _spans(self, t: FloatArray, actuators: IndexArray
               ) -> tuple[IndexArray, IndexArray, IndexArray]:
        """Return (row, lo, hi): each edge takes samples [lo, hi) of ``t`` (sorted) from row.

        ``row`` indexes ``actuators`` (grid row-major indices, as ``actuator`` counts them).
        """
        mine, rows = self._pairs_of(actuators)  # a tile of a 64 x 64 grid: a few of a million
        lo = np.searchsorted(t, self.start_s[mine] - self.before_s, side="left")
        hi = np.searchsorted(t, self.end_s[mine] + self.after_s, side="right")
        if self.examined is not None:
            # actuators never examined take every examined actuator's edges
            unexamined = np.flatnonzero(~np.isin(actuators, self.examined))
            if unexamined.size:
                lo_all = np.searchsorted(t, self.start_s - self.before_s, side="left")
                hi_all = np.searchsorted(t, self.end_s + self.after_s, side="right")
                spans = np.unique(np.stack([lo_all, hi_all], axis=1), axis=0)  # one per edge
                rows = np.concatenate([rows, np.repeat(unexamined, spans.shape[0])])
                lo = np.concatenate([lo, np.tile(spans[:, 0], unexamined.size)])
                hi = np.concatenate([hi, np.tile(spans[:, 1], unexamined.size)])
        return rows, lo, hi

    def excluded(self, t: FloatArray, actuators: IndexArray) -> BoolArray:
        """Return (len(actuators), len(t)): the pairs of samples at ``t`` [s] taken out.

        ``actuators`` are grid row-major indices (as ``actuator`` counts them).
        """
        out = np.zeros((actuators.size, t.size), dtype=bool)
        if not self.actuator.size or not t.size:
            return out
        order = None
        if np.any(np.diff(t) < 0):
            order = np.argsort(t, kind="stable")
            t = t[order]
        rows, lo, hi = self._spans(t, actuators)
        for first in range(0, actuators.size, COLUMNS):  # bounded (COLUMNS, n) counters
            pick = (rows >= first) & (rows < first + COLUMNS)
            width = min(COLUMNS, actuators.size - first)
            cell = (rows[pick] - first) * (t.size + 1)
            size = width * (t.size + 1)
            count = (np.bincount(cell + lo[pick], minlength=size)
                     - np.bincount(cell + hi[pick], minlength=size)).reshape(width, -1)
            out[first : first + width] = np.cumsum(count, axis=1)[:, :-1] > 0
        if order is not None:
            back = np.empty_like(order)
            back[order] = np.arange(order.size)
            out = out[:, back]
        return out

    def excluded_counts(self, t: FloatArray, actuators: IndexArray) -> IntArray:
        """Return how many samples at ``t`` [s] each of ``actuators`` loses (len(actuators),).

        The sum over :meth:`excluded`'s rows without its (actuators, samples) array: each
        actuator's spans merged where they overlap (a 64 x 64 grid's own edges are over a
        million pairs).
        """
        if not self.actuator.size or not t.size or not actuators.size:
            return np.zeros(actuators.size, np.int64)
        rows, lo, hi = self._spans(np.sort(t), actuators)
        # sorted by (actuator, start), each actuator's spans lifted above the one before:
        # a running maximum of the ends then never carries from one actuator to the next
        lift = rows.astype(np.int64) * (t.size + 1)
        order = np.lexsort((lo, rows))
        lo, hi = lo[order] + lift[order], hi[order] + lift[order]
        covered_to = np.maximum.accumulate(hi)
        start = np.maximum(lo, np.concatenate([[np.iinfo(np.int64).min], covered_to[:-1]]))
        new = np.maximum(hi - start, 0)
        return np.bincount(rows[order], weights=new, minlength=actuators.size).astype(np.int64)


@dataclass(frozen=True)
class EdgeExclusion:
    """What the unresolvable command edges take out of the (sample, actuator) pairs.

    Attributes:
        edges: command intervals found to be an edge for at least one actuator.
        pairs: (edge interval, actuator) pairs (an actuator's own edges, summed).
        samples: displacement samples the rule was applied to.
        actuators: actuators the rule was applied to.
        example_times_s: bag times of the first edges' earlier command stamps [s].
        before_s, after_s: pairs excluded from this long before an edge's interval to
            this long after it [s].
        delay_s: the delay the window was made for (None: the delay search's window).
        per_actuator_edges: (actuators,) edge intervals of each actuator's own command.
        per_actuator_excluded: (actuators,) samples each actuator loses to its edges.

    """

    edges: int
    pairs: int
    samples: int
    actuators: int
    example_times_s: tuple[float, ...]
    before_s: float
    after_s: float
    delay_s: float | None
    per_actuator_edges: tuple[int, ...]
    per_actuator_excluded: tuple[int, ...]

    @property
    def excluded_pairs(self) -> int:
        """Return the (sample, actuator) pairs excluded."""
        return int(sum(self.per_actuator_excluded))

    @property
    def fraction(self) -> float:
        """Return the fraction of the (sample, actuator) pairs excluded."""
        return self.excluded_pairs / max(self.samples * self.actuators, 1)

    def as_dict(self) -> dict[str, Any]:
        """Return the exclusion as calibration.json writes it (``data.command_edges``)."""
        return {
            "edges": self.edges,
            "pairs": self.pairs,
            "excluded_pairs": self.excluded_pairs,
            "excluded_fraction": self.fraction,
            "example_times_s": list(self.example_times_s),
            "excluded_before_s": self.before_s,
            "excluded_after_s": self.after_s,
            "delay_s": self.delay_s,
            "per_actuator": {
                "edges": list(self.per_actuator_edges),
                "excluded_samples": list(self.per_actuator_excluded),
            },
        }


def _window_max(values: FloatArray, side: str) -> FloatArray:
    """Return per row the max of the ``LOCAL_WINDOW`` - 1 rows beside it, its neighbours out.

    ``side`` "before": the rows ending 2 before it; "after": those starting 2 after it
    (inf where the window reaches past an end of the record: that side does not count).
    """
    size = LOCAL_WINDOW - 1
    out = np.full_like(values, np.inf)
    if values.shape[0] < 3:
        return out
    if side == "before":  # trailing window [j - size + 1, j], read at j = i - 2
        trail = maximum_filter1d(values, size, axis=0, mode="constant", cval=np.inf,
                                origin=(size - 1) // 2)
        out[2:] = trail[:-2]
    else:  # leading window [j, j + size - 1], read at j = i + 2
        lead = maximum_filter1d(values, size, axis=0, mode="constant", cval=np.inf,
                               origin=-(size // 2))
        out[:-2] = lead[2:]
    return out


def _interval_geometry(times: FloatArray, period: float
                       ) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Return the intervals' lengths (1 where not regular), the middle ones' weights, usable.

    For :func:`departures`: ``length`` (Nc - 1,), and for each interval but the first and
    last the weight of its midpoint between its neighbours' and whether all three are
    regular (Nc - 3,).
    """
    step = np.diff(times)
    regular = (step > 0.0) & (step <= GAP_FACTOR * period)
    length = np.where(regular, step, 1.0)
    mid = times[:-1] + 0.5 * step
    span = mid[2:] - mid[:-2]
    w = np.where(span > 0.0, (mid[1:-1] - mid[:-2]) / np.where(span > 0.0, span, 1.0), 0.5)
    usable = regular[:-2] & regular[1:-1] & regular[2:]
    return length, w, usable


def departures(times: FloatArray, command: FloatArray,
               period: float | None = None) -> FloatArray:
    """Return each command interval's departure (Nc - 1, A) [V] (see the module docstring).

    ``times`` (Nc,) [s] are the command stamps, ``command`` (Nc, A) [V] finite values,
    ``period`` the command period [s] (None: the median step of ``times``). The first and
    last intervals, and those next to a gap or a repeated stamp, get 0.
    """
    if period is None:
        period = float(np.median(np.diff(times)))
    length, w, usable = _interval_geometry(times, period)
    slope = np.diff(command, axis=0) / length[:, None]
    out = np.zeros_like(slope)
    if slope.shape[0] < 3:
        return out
    predicted = slope[:-2] + (slope[2:] - slope[:-2]) * w[:, None]
    out[1:-1] = np.where(usable[:, None], np.abs(slope[1:-1] - predicted) * period, 0.0)
    return out


def edge_pairs(
    times: FloatArray, command: FloatArray
) -> tuple[IndexArray, IndexArray]:
    """Return the (interval, actuator) pairs where an actuator's command has an edge.

    ``times`` (Nc,) [s] sorted stamps, ``command`` (Nc, A) [V] finite values (NaN held
    from the last finite value, as align.py does). Interval i runs from stamp i to i + 1.
    Pairs are sorted by interval, then actuator.
    """
    found: list[tuple[IndexArray, IndexArray]] = []
    if command.size and times.size > 1:
        floor = EDGE_FLOOR * float(command.max() - command.min())
        period = float(np.median(np.diff(times)))
        for lo in range(0, command.shape[1], COLUMNS):  # bounded temporaries, few chunks
            hi = min(lo + COLUMNS, command.shape[1])
            interval, column, _ = _candidates(times, command, columns=(lo, hi), period=period,
                                              floor=floor, decide=(0, times.size - 1))
            found.append((interval, column + lo))
    return _sorted_pairs(found)


def _candidates(times: FloatArray, command: FloatArray, *, columns: tuple[int, int],
                period: float, floor: float, decide: tuple[int, int]
                ) -> tuple[IndexArray, IndexArray, FloatArray]:
    """Return (interval, column, departure) of the edges among the intervals ``decide``.

    An edge as the module docstring says, with ``floor`` [V] as its floor, in the
    ``columns`` [lo, hi) of ``command``; ``decide`` is the [first, stop) of the intervals to
    test (the others only lend their departures). Columns count from ``lo``. Compiled
    where the kernels are fused (:mod:`.edge_loop`, the same pairs).
    """
    first, stop = decide
    lo, hi = columns
    if default_backend() is Backend.FUSED and times.size > 1:
        from es_calibration.data.edge_loop import departure_rows, edge_hits

        length, w, usable = _interval_geometry(times, period)
        dep = np.empty((times.size - 1, hi - lo))
        departure_rows(command, lo, length, w, usable, period, dep)
        room = 1024
        while True:  # edges are rare: room for a few, again with room for all if not
            interval = np.empty(room, np.intp)
            column = np.empty(room, np.intp)
            found = edge_hits(dep, first, stop, floor, EDGE_RATIO, LOCAL_WINDOW, interval,
                              column)
            if found <= room:
                break
            room = found
        interval, column = interval[:found], column[:found]
    else:
        dep = departures(times, command[:, lo:hi], period)
        local = np.minimum(_window_max(dep, "before"), _window_max(dep, "after"))
        edge = (dep > EDGE_RATIO * local) & (dep > floor)
        edge[:first] = False
        edge[stop:] = False
        interval, column = np.nonzero(edge)
    return interval.astype(np.intp), column.astype(np.intp), dep[interval, column]


def _sorted_pairs(found: list[tuple[IndexArray, IndexArray]]) -> tuple[IndexArray, IndexArray]:
    """Return the (interval, actuator) pairs of ``found``, sorted by interval, then actuator."""
    if not found:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    interval = np.concatenate([f[0] for f in found]).astype(np.intp)
    actuator = np.concatenate([f[1] for f in found]).astype(np.intp)
    order = np.lexsort((actuator, interval))
    return interval[order], actuator[order]


class EdgeStream:
    """The pairs of :func:`edge_pairs` over a command fed in stamp order, a chunk at a time.

    For the grid-wide refit, which never holds a whole grid's command (recording.gather):
    each chunk is examined with the rows before it that its first intervals'
    neighbourhoods read, and an interval is decided once the rows its neighbourhood reads
    after it have come. The floor (``EDGE_FLOOR`` x the command range) needs the whole
    record's range: an interval is kept when it passes the floor of the range so far (the
    range only grows) with its departure, and :meth:`pairs` applies the record's floor.
    """

    #: Command rows before and after an interval's own that its decision reads: its window's
    #: departures reach ``LOCAL_WINDOW`` intervals to each side, a departure the rows of
    #: its interval and one more on each side.
    _ROWS_BEFORE: Final = LOCAL_WINDOW + 1
    _ROWS_AFTER: Final = LOCAL_WINDOW + 2
    #: Actuators examined at once (bounds the temporaries).
    _COLUMNS: Final = 512

    def __init__(self, times: FloatArray, width: int) -> None:
        """Expect ``times`` (Nc,) [s] (every command stamp) and rows of ``width`` actuators."""
        self.times = np.asarray(times, np.float64)
        step = np.diff(self.times)
        self.period = float(np.median(step)) if step.size else 0.0
        self._rows = np.zeros((0, width))
        self._start = 0  # command index of self._rows[0]
        self._decided = 0  # intervals before this one are decided
        self._range = (np.inf, -np.inf)
        self._found: list[tuple[IndexArray, IndexArray, FloatArray]] = []

    def feed(self, held: FloatArray) -> None:
        """Take the next rows (n, width) [V] of the command (finite, NaN held).

        Raises:
            RecordingError: more rows than ``times`` has stamps.

        """
        if not held.size:
            return
        self._range = (min(self._range[0], float(held.min())),
                       max(self._range[1], float(held.max())))
        rows = np.concatenate([self._rows, held]) if self._rows.size else held
        end = self._start + rows.shape[0]
        if end > self.times.size:
            raise RecordingError(f"the recording has more commands than its time base "
                                 f"{self.times.size} command stamps")
        last = end >= self.times.size  # the record's last row is in
        # an interval is decided when the departures of its window are those of the record
        upto = end - 1 if last else end - self._ROWS_AFTER
        if upto > self._decided and rows.shape[0] > 1:
            times = self.times[self._start:end]
            floor = EDGE_FLOOR * (self._range[1] - self._range[0])
            decide = (self._decided - self._start, upto - self._start)
            for lo in range(0, rows.shape[1], self._COLUMNS):
                hi = min(lo + self._COLUMNS, rows.shape[1])
                interval, column, dep = _candidates(times, rows, columns=(lo, hi),
                                                    period=self.period, floor=floor,
                                                    decide=decide)
                self._found.append((interval + self._start, column + lo, dep))
            self._decided = upto
        keep_from = max(self._start, self._decided - self._ROWS_BEFORE)
        self._rows = rows[keep_from - self._start:].copy()
        self._start = keep_from

    def pairs(self) -> tuple[IndexArray, IndexArray]:
        """Return the (interval, actuator) pairs of the rows fed, with the record's floor."""
        floor = EDGE_FLOOR * (self._range[1] - self._range[0]) if self._found else 0.0
        return _sorted_pairs([(i[d > floor], c[d > floor]) for i, c, d in self._found])

    def mask(self) -> EdgeMask:
        """Return the pairs as a mask with the delay search's window (as :func:`edge_mask`).

        Its pairs are sorted by actuator (:attr:`EdgeMask.by_actuator`).
        """
        interval, actuator = self.pairs()
        order = np.argsort(actuator, kind="stable")
        interval, actuator = interval[order], actuator[order]
        before, after = search_window(self.period)
        return EdgeMask(self.times[interval], self.times[interval + 1], actuator, before, after,
                        by_actuator=True)


def find_edges(times: FloatArray, command: FloatArray) -> IndexArray:
    """Return the indices i of the intervals (stamps i to i + 1) that are an edge for any actuator.

    ``times`` (Nc,) [s] sorted stamps, ``command`` (Nc, A) [V] finite values.
    """
    return np.unique(edge_pairs(times, command)[0])


def edge_mask(times: FloatArray, command: FloatArray) -> EdgeMask:
    """Return the per-actuator edges of a command with the delay search's window.

    ``times`` (Nc,) [s] sorted stamps, ``command`` (Nc, A) [V] finite values.
    """
    interval, actuator = edge_pairs(times, command)
    step = np.diff(times)
    period = float(np.median(step)) if step.size else 0.0
    before, after = search_window(period)
    return EdgeMask(times[interval], times[interval + 1], actuator, before, after)


def account(mask: EdgeMask, t: FloatArray, actuators: int) -> EdgeExclusion:
    """Return what ``mask`` takes out of the samples at ``t`` (N,) [s] of ``actuators``.

    The mask's times must be on the time base of ``t``.
    """
    excluded = mask.excluded_counts(t, np.arange(actuators, dtype=np.intp))
    starts = np.unique(mask.start_s)
    return EdgeExclusion(
        edges=int(starts.size),
        pairs=int(mask.actuator.size),
        samples=int(t.size),
        actuators=actuators,
        example_times_s=tuple(float(x) for x in starts[:EXAMPLES]),
        before_s=mask.before_s,
        after_s=mask.after_s,
        delay_s=mask.delay_s,
        per_actuator_edges=tuple(int(n) for n in np.bincount(mask.actuator, minlength=actuators)),
        per_actuator_excluded=tuple(int(n) for n in excluded),
    )
