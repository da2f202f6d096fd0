"""Gaps and holes in measured topics: the one definition, and the samples they take out.

A *gap* in a topic is an interval between two consecutive messages longer than
``GAP_FACTOR`` (3.5) times that topic's median message period, i.e. at least three messages
missing in a row (stamps that repeat are first spread as in data/stamps.py, so a lagging recorder
does not make gaps). One or two dropped messages (2 or 3 periods, as random drops give) are
not a gap; their samples are simply absent, never interpolated. Data inside a gap are
unknown and nothing is interpolated across one. ``align.align`` removes the displacement
samples that would need them:

- temperature gap from message a to message b: the temperature between a and b would be a
  straight line, so samples in (a, b) go; so do samples within the half-window of the
  temperature-rate estimate on either side (their dT/dt would use the straight line).
  Effects with memory that act on the temperature are evaluated from T and dT/dt only, so
  no state has to be restarted.
- command hole from message a to message b: the command in effect from a + one command
  period (when the next command was due) is unknown until b, and effects with memory
  need the commands before a sample: samples from a + one period to b +
  ``COMMAND_SETTLING_S`` go. The margin covers the longest delay searched (0.1 s) and the
  play operator's state, which is unknown after a hole until the command has swept its range
  again (a characterisation profile does so within a second: its slowest tone is >= 1 Hz).
- displacement gap: there are no samples to remove; the gap is reported.

A topic that starts later or ends earlier than the displacement record by more than
``GAP_FACTOR`` periods has a gap at that end, with the same rules (the samples before the
first command are dropped anyway; a late first command still takes its settling margin).
Gap times are on the bag's time base [s].

Shorter than that, the ends of a slow temperature topic still leave samples without a
temperature on both sides: a 1 Hz sensor's last message can come most of a second before the
record ends, while the temperature moves by a degree per second. Their temperature would be
an extrapolation (the last message held), so the samples before the first temperature
message and after the last one go too (:func:`exclude_outside_span`), counted apart.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any, Final

import numpy as np

from es_calibration.data.stamps import repeated, spread_repeated
from es_calibration.errors import CalibrationError
from es_common.arrays import BoolArray, FloatArray

#: An interval between consecutive messages longer than this many median periods is a gap.
GAP_FACTOR: Final = 3.5
#: Samples excluded after the end of a command hole [s] (see the module docstring).
COMMAND_SETTLING_S: Final = 1.0


#: What a gap in each measured topic means for the samples (see the module docstring).
ROLES: Final = ("command", "displacement", "temperature")


@dataclass(frozen=True)
class Gap:
    """One gap in a topic.

    Attributes:
        topic: the topic's name.
        role: "command", "displacement" or "temperature" (``ROLES``).
        start_s: bag time of the last message before the gap [s].
        duration_s: time from that message to the next one [s].
        missing_samples: messages the topic's median period would have put in the gap.
        period_s: the topic's median message period [s].
        excluded_samples: displacement samples this gap takes out of fit and scoring (gaps
            whose margins overlap count the shared samples each).

    """

    topic: str
    role: str
    start_s: float
    duration_s: float
    missing_samples: int
    period_s: float
    excluded_samples: int = 0

    @property
    def end_s(self) -> float:
        """Return the bag time of the first message after the gap [s]."""
        return self.start_s + self.duration_s

    def as_dict(self) -> dict[str, Any]:
        """Return the gap as calibration.json writes it (``data.gaps``)."""
        return {
            "topic": self.topic,
            "start_s": self.start_s,
            "duration_s": self.duration_s,
            "missing_samples": self.missing_samples,
            "excluded_samples": self.excluded_samples,
        }

    def excluded_interval(self, temperature_margin_s: float) -> tuple[float, float] | None:
        """Return the closed interval [s] of sample times this gap excludes (None: none).

        ``temperature_margin_s`` is the half-window of the temperature-rate estimate [s].
        """
        if self.role == "command":
            return self.start_s + self.period_s * (1.0 - 1e-3), self.end_s + COMMAND_SETTLING_S
        if self.role == "temperature":
            return self.start_s - temperature_margin_s, self.end_s + temperature_margin_s
        return None


@dataclass(frozen=True)
class TemperatureSpan:
    """The samples outside the temperature topic's time span, which its ends take out.

    Attributes:
        start_s, end_s: bag times of the first and the last temperature message [s].
        excluded_before, excluded_after: displacement samples before ``start_s`` and after
            ``end_s`` left out of fit and scoring (after any gap's).

    """

    start_s: float
    end_s: float
    excluded_before: int
    excluded_after: int

    @property
    def excluded_samples(self) -> int:
        """Return the samples excluded at both ends."""
        return self.excluded_before + self.excluded_after

    def as_dict(self) -> dict[str, Any]:
        """Return the span as calibration.json writes it (``data.temperature_span``)."""
        return asdict(self)


def exclude_outside_span(
    t: FloatArray, temperature_times: FloatArray
) -> tuple[BoolArray, TemperatureSpan]:
    """Return the samples at times ``t`` (N,) [s] outside the temperature topic's span.

    ``temperature_times`` (Nt,) [s] are the sorted temperature stamps on the same time base.
    A sample at a message's own stamp keeps its (measured) temperature.
    """
    start, end = float(temperature_times[0]), float(temperature_times[-1])
    before, after = t < start, t > end
    span = TemperatureSpan(start, end, int(before.sum()), int(after.sum()))
    return before | after, span


def _spread(times: FloatArray) -> FloatArray:
    return spread_repeated(times) if repeated(times).any() else times


def _missing(periods: float, edge: bool) -> int:
    """Return the messages missing in a gap of ``periods`` median periods.

    Inside the record a gap between two messages lacks round(periods) - 1 of them; at an end
    of the record the messages due within it number floor(periods).
    """
    return max(int(np.floor(periods + 1e-6)) if edge else round(periods) - 1, 1)


def find_gaps(
    topic: str, role: str, times: FloatArray, record: tuple[float, float] | None = None
) -> list[Gap]:
    """Return the gaps of ``topic`` whose sorted message stamps are ``times`` [s].

    ``record`` is the span [s] of the displacement record: a topic that starts later or ends
    earlier than it by more than ``GAP_FACTOR`` periods has a gap at that end too (a leading
    gap starts at the record's start). Needs at least two distinct stamps.

    Raises:
        CalibrationError: ``role`` is not one of ``ROLES``.

    """
    if role not in ROLES:
        raise CalibrationError(f"unknown role {role!r} of topic {topic} (expected one of {ROLES})")
    spread = _spread(times)
    period = float(np.median(np.diff(spread)))
    starts, steps, edge = spread[:-1], np.diff(spread), np.zeros(spread.size - 1, dtype=bool)
    if record is not None:
        starts = np.concatenate([[record[0]], starts, [spread[-1]]])
        steps = np.concatenate([[spread[0] - record[0]], steps, [record[1] - spread[-1]]])
        edge = np.concatenate([[True], edge, [True]])
    return [
        Gap(
            topic=topic,
            role=role,
            start_s=float(starts[i]),
            duration_s=float(steps[i]),
            missing_samples=_missing(float(steps[i]) / period, bool(edge[i])),
            period_s=period,
        )
        for i in np.flatnonzero(steps > GAP_FACTOR * period)
    ]


def exclude(
    t: FloatArray, gaps: list[Gap], temperature_margin_s: float
) -> tuple[BoolArray, dict[str, int], list[Gap]]:
    """Return what the gaps take out of the samples at times ``t`` (N,) [s].

    Returns the excluded samples (N,), their count per role (only roles whose gaps exclude
    something) and the gaps with their own counts.
    """
    per_role = {role: np.zeros(t.shape, dtype=bool) for role in ROLES}
    counted = []
    for gap in gaps:  # a handful of gaps, each a vectorised mask over the samples
        bounds = gap.excluded_interval(temperature_margin_s)
        n = 0
        if bounds is not None:
            mask = (t >= bounds[0]) & (t <= bounds[1])
            per_role[gap.role] |= mask
            n = int(mask.sum())
        counted.append(replace(gap, excluded_samples=n))
    out = np.logical_or.reduce(list(per_role.values()))
    counts = {role: int(m.sum()) for role, m in per_role.items() if m.any()}
    return out, counts, counted
