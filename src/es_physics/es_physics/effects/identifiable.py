"""What a record can show of a parameter: the one statement of each identifiable range.

An effect declares, per reported parameter (:meth:`Effect.reported`'s names), which rule
says whether a fitted value is something the data can show (:attr:`Effect.identifiable`).
A value outside it is a stand-in: the effect took up something else (a reference
temperature far outside the recorded temperatures, a "time constant" of a sample or two,
or longer than the record can show). :func:`identification_problem` applies the rules to a
record's :class:`RecordSpan`.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

#: Shortest time constant a record shows: this many sample periods (a shorter one is a
#: step, something in the timing, not a filter).
MIN_TIME_CONSTANT_SAMPLES: Final = 4.0
#: Longest time constant a record shows: this fraction of its length (beyond, a filter is
#: a slope: drift or something else).
MAX_TIME_CONSTANT_FRACTION: Final = 0.5
#: A temperature counts as inside the recorded range widened by this fraction of the range
#: on each side (and at least ``MIN_TEMPERATURE_MARGIN_DEGC``): sensor offsets and noise.
TEMPERATURE_MARGIN_FRACTION: Final = 0.25
#: Smallest margin around the recorded temperature range [degC].
MIN_TEMPERATURE_MARGIN_DEGC: Final = 0.5
#: A time shift shows when it exceeds this many times the displacement stamps' jitter (a
#: shift within it may be the stamps' own lateness: receive times, not sampling times).
STAMP_JITTER_MULTIPLE: Final = 2.0


class Identifiable(enum.Enum):
    """The kind of range a record can identify a parameter in.

    ``INSIDE_TEMPERATURE_RANGE``: a temperature [degC] inside the recorded range;
    ``TIME_CONSTANT``: a time [s] between a few sample periods and a fraction of the record;
    ``CORNER_FREQUENCY``: a frequency [Hz] between one cycle in that fraction of the record
    and a few samples a cycle; ``BEYOND_STAMP_JITTER``: a time shift [s] beyond
    ``STAMP_JITTER_MULTIPLE`` times the jitter of the displacement stamps.
    """

    INSIDE_TEMPERATURE_RANGE = "inside_temperature_range"
    TIME_CONSTANT = "time_constant"
    CORNER_FREQUENCY = "corner_frequency"
    BEYOND_STAMP_JITTER = "beyond_stamp_jitter"


@dataclass(frozen=True)
class RecordSpan:
    """What a record spans: its temperatures [degC], sample period [s] and length [s].

    ``stamp_jitter_s`` is the displacement stamps' jitter [s rms] when they are receive
    times (0: sampling times).
    """

    temperature_low: float
    temperature_high: float
    sample_period_s: float
    duration_s: float
    stamp_jitter_s: float = 0.0

    def temperature_bounds(self) -> tuple[float, float]:
        """Return the recorded temperature range with its margin [degC]."""
        span = self.temperature_high - self.temperature_low
        margin = max(TEMPERATURE_MARGIN_FRACTION * span, MIN_TEMPERATURE_MARGIN_DEGC)
        return self.temperature_low - margin, self.temperature_high + margin

    def time_bounds(self) -> tuple[float, float]:
        """Return the time constants the record shows [s]."""
        return (
            MIN_TIME_CONSTANT_SAMPLES * self.sample_period_s,
            MAX_TIME_CONSTANT_FRACTION * self.duration_s,
        )


def _problem(name: str, value: float, rule: Identifiable, span: RecordSpan) -> str | None:
    """Return why ``value`` of parameter ``name`` is outside what ``span`` shows, or None."""
    if rule is Identifiable.INSIDE_TEMPERATURE_RANGE:
        low, high = span.temperature_bounds()
        if not low <= value <= high:
            return (
                f"{name} {value:.3g} degC outside the recorded temperatures "
                f"{span.temperature_low:.3g}-{span.temperature_high:.3g} degC"
            )
        return None
    if rule is Identifiable.BEYOND_STAMP_JITTER:
        limit = STAMP_JITTER_MULTIPLE * span.stamp_jitter_s
        if abs(value) <= limit:
            return (
                f"{name} {value * 1e3:.3g} ms within {STAMP_JITTER_MULTIPLE:g} x the "
                f"displacement stamps' jitter {span.stamp_jitter_s * 1e3:.3g} ms rms (receive "
                "times: their own lateness looks like a delay)"
            )
        return None
    low, high = span.time_bounds()
    if rule is Identifiable.TIME_CONSTANT and not low <= value <= high:
        return (
            f"{name} {value:.3g} s outside what the record shows ({MIN_TIME_CONSTANT_SAMPLES:g} "
            f"samples {low:.3g} s to {MAX_TIME_CONSTANT_FRACTION:g} x the record {high:.3g} s)"
        )
    # a corner shows between one cycle in the allowed part of the record and
    # MIN_TIME_CONSTANT_SAMPLES samples per cycle
    f_low, f_high = 1.0 / high, 1.0 / (MIN_TIME_CONSTANT_SAMPLES * span.sample_period_s)
    if rule is Identifiable.CORNER_FREQUENCY and not f_low <= value <= f_high:
        return (
            f"{name} {value:.3g} Hz outside what the record shows ({f_low:.3g} Hz: one cycle "
            f"in {MAX_TIME_CONSTANT_FRACTION:g} x the record, to {f_high:.3g} Hz: "
            f"{MIN_TIME_CONSTANT_SAMPLES:g} samples a cycle)"
        )
    return None


def identification_problem(
    rules: Mapping[str, Identifiable], reported: Mapping[str, float], span: RecordSpan
) -> str | None:
    """Return why a reported parameter lies outside what the record shows, or None.

    Args:
        rules: the effect's :attr:`Effect.identifiable` (reported name -> rule).
        reported: the effect's reported parameters.
        span: the record's temperatures, sample period and length.

    """
    for name, rule in rules.items():
        value = reported.get(name)
        if value is None:
            continue
        if not math.isfinite(value):
            return f"{name} is not a number"
        problem = _problem(name, float(value), rule, span)
        if problem:
            return problem
    return None
