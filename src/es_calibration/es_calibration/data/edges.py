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
- the samples excluded for an edge are those whose input could read the interval at any
  shift the delay search considers (delayrange.py), with the interpolation's reach of one
  period and a margin of ``EDGE_MARGIN_PERIODS`` on each side: the same samples for every
  candidate model, so candidates are compared on the same samples.

With several actuators (the screening block) an interval is an edge when it is one for any
of them, and the samples go for all of them (the grid refit uses the same samples).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from scipy.ndimage import maximum_filter1d

from es_calibration._typing import BoolArray, FloatArray
from es_calibration.data.delayrange import shift_span
from es_calibration.data.gaps import GAP_FACTOR

#: An interval whose departure exceeds this many times its neighbourhood's is an edge.
EDGE_RATIO: Final = 3.0
#: Intervals on each side whose departures make the neighbourhood.
LOCAL_WINDOW: Final = 8
#: Departures below this fraction of the actuators' command range are never edges.
EDGE_FLOOR: Final = 1e-3
#: Margin on each side of an edge's excluded span [command periods].
EDGE_MARGIN_PERIODS: Final = 1.0
#: Edges whose times the report and calibration.json list.
EXAMPLES: Final = 5
#: Actuators whose departures are computed at once (bounds the temporaries).
COLUMNS: Final = 16


@dataclass(frozen=True)
class EdgeExclusion:
    """What the unresolvable command edges take out of the samples.

    Attributes:
        edges: command intervals found to be edges.
        excluded_samples: displacement samples left out for them (after any gap's).
        samples: displacement samples the rule was applied to.
        example_times_s: bag times of the first edges' earlier command stamps [s].
        before_s, after_s: samples excluded from this long before an edge's interval to
            this long after it [s].

    """

    edges: int
    excluded_samples: int
    samples: int
    example_times_s: tuple[float, ...]
    before_s: float
    after_s: float

    @property
    def fraction(self) -> float:
        """Return the fraction of the samples excluded."""
        return self.excluded_samples / max(self.samples, 1)

    def as_dict(self) -> dict[str, Any]:
        """Return the exclusion as calibration.json writes it (``data.command_edges``)."""
        return {
            "edges": self.edges,
            "excluded_samples": self.excluded_samples,
            "excluded_fraction": self.fraction,
            "example_times_s": list(self.example_times_s),
            "excluded_before_s": self.before_s,
            "excluded_after_s": self.after_s,
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


def departures(times: FloatArray, command: FloatArray) -> FloatArray:
    """Return each command interval's departure (Nc - 1, A) [V] (see the module docstring).

    ``times`` (Nc,) [s] are the command stamps, ``command`` (Nc, A) [V] finite values. The
    first and last intervals, and those next to a gap or a repeated stamp, get 0.
    """
    step = np.diff(times)
    period = float(np.median(step))
    regular = (step > 0.0) & (step <= GAP_FACTOR * period)
    length = np.where(regular, step, 1.0)
    slope = np.diff(command, axis=0) / length[:, None]
    mid = times[:-1] + 0.5 * step
    out = np.zeros_like(slope)
    if slope.shape[0] < 3:
        return out
    span = mid[2:] - mid[:-2]
    w = np.where(span > 0.0, (mid[1:-1] - mid[:-2]) / np.where(span > 0.0, span, 1.0), 0.5)
    predicted = slope[:-2] + (slope[2:] - slope[:-2]) * w[:, None]
    usable = regular[:-2] & regular[1:-1] & regular[2:]
    out[1:-1] = np.where(usable[:, None], np.abs(slope[1:-1] - predicted) * period, 0.0)
    return out


def find_edges(times: FloatArray, command: FloatArray) -> npt.NDArray[np.intp]:
    """Return the indices i of the edge intervals (stamps i to i + 1) of a command.

    ``times`` (Nc,) [s] sorted stamps, ``command`` (Nc, A) [V] finite values (NaN held
    from the last finite value, as align.py does).
    """
    edge = np.zeros(max(times.size - 1, 0), dtype=bool)
    if not command.size:
        return np.flatnonzero(edge)
    floor = EDGE_FLOOR * float(command.max() - command.min())
    for lo in range(0, command.shape[1], COLUMNS):  # bounded temporaries, few chunks
        dep = departures(times, command[:, lo : lo + COLUMNS])
        local = np.minimum(_window_max(dep, "before"), _window_max(dep, "after"))
        edge |= ((dep > EDGE_RATIO * local) & (dep > floor)).any(axis=1)
    return np.flatnonzero(edge)


def exclude_edges(
    t: FloatArray, command_times: FloatArray, command: FloatArray
) -> tuple[BoolArray, EdgeExclusion]:
    """Return the samples at times ``t`` (N,) [s] that unresolvable command edges exclude.

    ``command_times`` (Nc,) [s] on the same time base, ``command`` (Nc, A) [V] finite.
    Returns the excluded samples (N,) and the account of them.
    """
    idx = find_edges(command_times, command)
    step = np.diff(command_times)
    period = float(np.median(step)) if step.size else 0.0
    lowest, highest = shift_span(period) if period > 0.0 else (0.0, 0.0)
    before = (1.0 + EDGE_MARGIN_PERIODS - lowest) * period
    after = (1.0 + EDGE_MARGIN_PERIODS + highest) * period
    starts = command_times[idx] - before
    ends = command_times[idx + 1] + after
    # a sample is inside some span when more spans have started than ended before it
    inside = np.searchsorted(np.sort(starts), t, side="right") - np.searchsorted(
        np.sort(ends), t, side="left"
    )
    out = np.asarray(inside > 0)
    account = EdgeExclusion(
        edges=int(idx.size),
        excluded_samples=int(out.sum()),
        samples=int(t.size),
        example_times_s=tuple(float(x) for x in command_times[idx[:EXAMPLES]]),
        before_s=before,
        after_s=after,
    )
    return out, account
