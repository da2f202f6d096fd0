"""Repeated time stamps in measured data: the rules (applied by ``align.align``) and helpers.

A recorder that lags under sim time stamps several messages of a topic with one clock value
(up to 80 % repeated stamps have been seen). Stamps then no longer say which command produced
which displacement, so the time-based zero-order hold of align.py would pair them wrongly.
Messages are always used in stamp order, and messages sharing a stamp in recording order (the
bag reader sorts stably). Then:

- every topic: the stamp of a lagging recorder is the clock it last saw, so the messages of a
  run of equal stamps were received at or after it. Where the times are needed (temperature
  always, displacement when paired by order) each run is spread evenly up to the next
  distinct stamp, at most at the typical period (a run just before a gap is not spread
  across it).
- command and displacement with as many messages each (lock-step recording, one displacement
  per command): they are paired by message order, displacement i being the response to
  command i. Displacement times are spread, and each command is placed midway between its
  displacement and the previous one.
- otherwise the pairing stays time based and every displacement sample whose pairing is
  ambiguous is dropped and counted: one that shares its stamp with another displacement, or
  whose command in effect is one of several commands sharing a stamp.
"""

from __future__ import annotations

import numpy as np

from es_common.arrays import BoolArray, FloatArray, IndexArray


def repeated(times: FloatArray) -> BoolArray:
    """Return which messages share their stamp with an earlier message (times sorted)."""
    out = np.zeros(times.shape, dtype=bool)
    out[1:] = times[1:] == times[:-1]
    return out


def _runs(times: FloatArray) -> tuple[IndexArray, IndexArray]:
    """Return the first index of every run of equal stamps, and each message's run number."""
    first = ~repeated(times)
    return np.flatnonzero(first), np.cumsum(first) - 1


def run_lengths(times: FloatArray) -> IndexArray:
    """Return, per message, how many messages share its stamp (times sorted)."""
    starts, run_of = _runs(times)
    return np.diff(np.append(starts, times.size))[run_of]


def spread_repeated(times: FloatArray) -> FloatArray:
    """Return strictly increasing times: each run of equal stamps spread up to the next stamp.

    The last run is spread at the mean message period of the rest of the record, and no run
    wider than the median run's period (a run just before a gap keeps the gap after it).
    Needs at least two distinct stamps.
    """
    starts, run_of = _runs(times)
    ends = np.append(starts[1:], times.size)
    next_stamp = np.append(times[starts[1:]], np.nan)
    last_period = (times[starts[-1]] - times[0]) / starts[-1]
    next_stamp[-1] = times[starts[-1]] + last_period * (ends[-1] - starts[-1])
    step = (next_stamp - times[starts]) / (ends - starts)
    # a run just before a gap is spread at the typical period, not across the gap
    step = np.minimum(step, np.median(step))
    position = np.arange(times.size) - starts[run_of]
    return np.asarray(times + position * step[run_of], dtype=np.float64)
