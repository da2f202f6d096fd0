"""Temperature sensor faults, found before the physics and repaired from the neighbours.

Each sensor (a column of the grid's temperature, row-major) is checked, vectorised over a
chunk of sensors at a time, for:

- ``sensor_flat``: no variation over the whole record;
- ``sensor_frozen``: the same value for at least ``FROZEN_MIN_SAMPLES`` samples (and
  ``FROZEN_MIN_FRACTION`` of the record) while most other sensors move;
- ``sensor_dropout``: non-finite samples while most other sensors read;
- ``sensor_out_of_range``: readings outside ``PLAUSIBLE_DEGC``;
- ``sensor_jump``: a step of the sensor against the grid's common temperature beyond
  ``JUMP_SIGMAS`` times its own sample-to-sample noise and ``JUMP_MIN_DEGC`` (a mount's
  thermal time constant is seconds: no sensor leaves its neighbours in one sample);
- ``sensor_noise_change``: its sample-to-sample noise changing by more than
  ``NOISE_CHANGE_RATIO`` between ``NOISE_WINDOWS`` parts of the record.

A faulty sample is replaced by the mean of its grid neighbours' good samples at that time
(the grid's median of good sensors when no neighbour is good; left out, NaN, when no sensor
is): the finding says which.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from itertools import pairwise
from typing import Final

import numpy as np

from es_calibration.health.findings import Finding
from es_common.arrays import BoolArray, FloatArray, IndexArray

#: Shortest run of identical values that counts as frozen [samples] (a 1 Hz logger over a
#: 30 s record freezes for a dozen readings; noisy readings never repeat eight times) ...
FROZEN_MIN_SAMPLES: Final = 8
#: ... and as a share of the record.
FROZEN_MIN_FRACTION: Final = 0.02
#: Share of the other sensors that must change meanwhile (the temperature did move).
OTHERS_MOVING: Final = 0.5
#: A single sensor (none to compare with) is frozen when its run of identical readings is
#: this many times its longest run elsewhere in the record (it otherwise moves).
SELF_RUN_RATIO: Final = 5
#: Readings a mirror's temperature sensor can give [degC].
PLAUSIBLE_DEGC: Final = (-40.0, 125.0)
#: A jump: a step against the common temperature beyond this many noise sigmas ...
JUMP_SIGMAS: Final = 10.0
#: ... and beyond this [degC].
JUMP_MIN_DEGC: Final = 0.3
#: Parts of the record whose noise levels are compared.
NOISE_WINDOWS: Final = 8
#: Noise levels below this count as this [degC]: a change among them does not matter to
#: the calibration (and a noise-free reading has none to compare).
NOISE_FLOOR_DEGC: Final = 0.005
#: Fewest samples in a part whose noise level is compared.
NOISE_WINDOW_SAMPLES: Final = 100
#: Ratio of the noisiest to the quietest part that counts as a change of noise level.
NOISE_CHANGE_RATIO: Final = 5.0
#: Sensors checked together (memory: a few chunk-sized copies of the record).
CHUNK: Final = 256
#: MAD to standard deviation of a normal distribution.
_MAD_SIGMA: Final = 1.4826


@dataclass(frozen=True)
class SensorHealth:
    """The sensors' findings and the repaired temperature.

    Attributes:
        findings: one per fault, in sensor order.
        temperature: (Nt, S) values with the faulty samples repaired (the input array
            itself when nothing was found).
        bad: (Nt, S) the samples found faulty.

    """

    findings: list[Finding]
    temperature: FloatArray
    bad: BoolArray


def _longest_run(flags: BoolArray) -> tuple[IndexArray, IndexArray]:
    """Return the longest run of True per column of ``flags`` (n, S): (length, last index)."""
    n = flags.shape[0]
    index = np.arange(n)[:, None]
    last_false = np.maximum.accumulate(np.where(flags, -1, index), axis=0)
    run = index - last_false
    end = np.argmax(run, axis=0)
    return run[end, np.arange(flags.shape[1])], end


def _subject(sensor: int, grid: tuple[int, int], n_sensors: int) -> tuple[str, int | None,
                                                                          int | None]:
    """Return the words, row and column naming ``sensor`` (row/col when one per actuator)."""
    if n_sensors == grid[0] * grid[1]:
        row, col = divmod(sensor, grid[1])
        return f"sensor {sensor} ({row}, {col})", row, col
    return f"sensor {sensor}", None, None


class _Checker:
    """The checks over one chunk of sensors (columns ``first`` .. of the record)."""

    def __init__(self, times: FloatArray, values: FloatArray, first: int) -> None:
        self.t = times
        self.x = values
        self.first = first
        self.finite = np.isfinite(values)
        self.step = np.diff(values, axis=0)
        self.bad = np.zeros(values.shape, dtype=bool)
        self.found: list[tuple[str, int, int, int, float, str, str]] = []

    def _add(self, kind: str, column: int, span: tuple[int, int], value: float,
             words: tuple[str, str]) -> None:
        """Record a finding: ``words`` are its unit and sentence."""
        self.found.append((kind, self.first + column, *span, value, *words))

    def flat_and_frozen(self) -> None:
        n, _S = self.x.shape
        same = self.step == 0.0  # NaN steps are not "same"
        length, last = _longest_run(same)
        moving = np.isfinite(self.step) & ~same
        minimum = max(FROZEN_MIN_SAMPLES, int(FROZEN_MIN_FRACTION * n))
        for column in np.flatnonzero(length + 1 >= minimum):
            start, end = int(last[column] - length[column] + 1), int(last[column] + 1)
            if length[column] >= n - 1:
                self.bad[:, column] = True
                self._add("sensor_flat", int(column), (0, n - 1), float(self.x[0, column]),
                          ("degC", f"reads {self.x[0, column]:.4g} degC over the whole record"))
                continue
            if self.x.shape[1] > 1:
                others = np.delete(moving[start:end], column, axis=1)
                if others.any(axis=0).mean() < OTHERS_MOVING:
                    continue  # the temperature itself held still
            else:  # one sensor: frozen only when it otherwise moves
                elsewhere = same[:, column].copy()
                elsewhere[start:end] = False
                if length[column] < SELF_RUN_RATIO * max(int(_longest_run(
                        elsewhere[:, None])[0][0]), 1):
                    continue
            self.bad[start : end + 1, column] = True
            self._add("sensor_frozen", int(column), (start, end), float(self.x[start, column]),
                      ("degC", f"stops updating at {self.x[start, column]:.4g} degC for "
                       f"{end - start + 1} samples while the other sensors move"))

    def dropouts(self) -> None:
        reading = self.finite.mean(axis=1) >= OTHERS_MOVING
        lost = ~self.finite & reading[:, None]
        for column in np.flatnonzero(lost.any(axis=0)):
            where = np.flatnonzero(lost[:, column])
            self.bad[where, column] = True
            self._add("sensor_dropout", int(column), (int(where[0]), int(where[-1])),
                      float(where.size),
                      ("samples",
                       f"gives no reading in {where.size} samples while the others read"))

    def out_of_range(self) -> None:
        low, high = PLAUSIBLE_DEGC
        with np.errstate(invalid="ignore"):
            outside = self.finite & ((self.x < low) | (self.x > high))
        for column in np.flatnonzero(outside.any(axis=0)):
            where = np.flatnonzero(outside[:, column])
            worst = float(self.x[where[np.argmax(np.abs(self.x[where, column]))], column])
            self.bad[where, column] = True
            self._add("sensor_out_of_range", int(column), (int(where[0]), int(where[-1])), worst,
                      ("degC", f"reads {worst:.4g} degC in {where.size} samples, outside the "
                       f"plausible {low:g} to {high:g} degC"))

    def _noise(self, steps: FloatArray) -> FloatArray:
        """Return each column's robust sample-to-sample noise (MAD) of ``steps``."""
        centred = steps - np.nanmedian(steps, axis=0)
        return np.asarray(_MAD_SIGMA * np.nanmedian(np.abs(centred), axis=0), np.float64)

    def jumps(self) -> None:
        if self.x.shape[1] < 2:
            return
        usable = np.where(self.bad, np.nan, self.x)
        with np.errstate(invalid="ignore"), _quiet():
            common = np.nanmedian(usable, axis=1, keepdims=True)
            own = np.diff(usable - common, axis=0)
            sigma = self._noise(own)
        limit = np.maximum(JUMP_SIGMAS * sigma, JUMP_MIN_DEGC)
        with np.errstate(invalid="ignore"):
            jumped = np.abs(own) > limit
        for column in np.flatnonzero(jumped.any(axis=0)):
            where = np.flatnonzero(jumped[:, column])
            size = own[where, column]
            # steps that cancel are a spell (back afterwards); else the offset stays
            end = int(where[-1]) if abs(size.sum()) < JUMP_MIN_DEGC and where.size > 1 else (
                self.x.shape[0] - 1)
            start = int(where[0]) + 1
            self.bad[start : end + 1, column] = True
            biggest = float(size[np.argmax(np.abs(size))])
            self._add("sensor_jump", int(column), (start, end), biggest,
                      ("degC", f"steps by {biggest:+.3g} degC against the other sensors in one "
                       f"sample ({where.size} step(s)), faster than a mount's temperature can "
                       "change"))

    def noise_change(self) -> None:
        n = self.step.shape[0]
        windows = min(NOISE_WINDOWS, n // NOISE_WINDOW_SAMPLES)
        if windows < 2 or self.x.shape[1] < 3:
            return  # without others to remove the common temperature, a ramp looks like noise
        with _quiet():
            usable = np.where(self.bad, np.nan, self.x)
            # second differences: a smooth difference between sensors (their own lags, a
            # gradient across the mirror) is no noise
            steps = np.diff(usable - np.nanmedian(usable, axis=1, keepdims=True), 2, axis=0)
        bad = self.bad[2:] | self.bad[1:-1] | self.bad[:-2]
        steps = np.where(bad, np.nan, steps)
        n = steps.shape[0]
        edges = np.linspace(0, n, windows + 1).astype(int)
        # half the 16-84 % spread: a sigma that one jump does not move, and wide enough that
        # quantised readings do not make it jump between 0 and a step (as a MAD does)
        with _quiet():
            level = np.stack([
                0.5 * np.diff(np.nanpercentile(steps[a:b], [16.0, 84.0], axis=0), axis=0)[0]
                for a, b in pairwise(edges)
            ])
            level = np.maximum(level, NOISE_FLOOR_DEGC)
            ratio = np.nanmax(level, axis=0) / np.nanmin(level, axis=0)
        for column in np.flatnonzero(ratio > NOISE_CHANGE_RATIO):
            mid = np.sqrt(np.nanmax(level[:, column]) * np.nanmin(level[:, column]))
            parts = np.flatnonzero(level[:, column] > mid)
            start, end = int(edges[parts[0]]), int(edges[parts[-1] + 1])
            self.bad[start : end + 1, column] = True
            self._add("sensor_noise_change", int(column), (start, end), float(ratio[column]),
                      ("x its quietest noise",
                       f"its noise rises {ratio[column]:.3g}x (second differences "
                       f"{np.nanmax(level[:, column]):.3g} degC rms) in part of the record"))


@contextmanager
def _quiet() -> Iterator[None]:
    """Silence numpy's warnings for all-NaN slices (they give NaN, which is handled)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def _repair(values: FloatArray, bad: BoolArray, grid: tuple[int, int]) -> tuple[FloatArray,
                                                                                list[str]]:
    """Return ``values`` with bad samples taken from good neighbours, and each sensor's action."""
    fixed = values.copy()
    S = values.shape[1]
    on_grid = grid[0] * grid[1] == S
    good = ~bad & np.isfinite(values)
    with _quiet():
        grid_median = np.nanmedian(np.where(good, values, np.nan), axis=1)
    actions = [""] * S
    for sensor in np.flatnonzero(bad.any(axis=0)):
        rows = np.flatnonzero(bad[:, sensor])
        fill = np.full(rows.size, np.nan)
        if on_grid:
            r, c = divmod(int(sensor), grid[1])
            around = ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1))
            near = np.array([rr * grid[1] + cc for rr, cc in around
                             if 0 <= rr < grid[0] and 0 <= cc < grid[1]], np.intp)
            ok = good[np.ix_(rows, near)]
            count = ok.sum(axis=1)
            total = np.where(ok, values[np.ix_(rows, near)], 0.0).sum(axis=1)
            fill = np.where(count > 0, total / np.maximum(count, 1), np.nan)
        from_median = ~np.isfinite(fill)
        fill[from_median] = grid_median[rows[from_median]]
        fixed[rows, sensor] = fill
        left_out = int(np.count_nonzero(~np.isfinite(fill)))
        parts = []
        if on_grid and np.any(~from_median):
            parts.append(f"{int(np.count_nonzero(~from_median))} samples taken from the mean "
                         "of its good neighbours")
        if np.any(from_median) and left_out < rows.size:
            parts.append(f"{int(np.count_nonzero(from_median)) - left_out} from the grid's "
                         "median")
        if left_out:
            parts.append(f"{left_out} samples left out")
        actions[sensor] = "; ".join(parts)
    return fixed, actions


def _single_sensor(times: FloatArray, values: FloatArray, start: float) -> SensorHealth:
    """Check one sensor read for the whole grid (every column the same) as one sensor."""
    one = check_sensors(times, values[:, :1], (1, 1), start)
    if not one.findings:
        return SensorHealth([], values, np.zeros(values.shape, dtype=bool))
    findings = [replace(f, subject="the single sensor of the grid", row=None, col=None,
                        sentence=f.sentence.replace("sensor 0 (0, 0)",
                                                    "the single sensor of the grid"))
                for f in one.findings]
    shape = values.shape
    return SensorHealth(findings, np.broadcast_to(one.temperature, shape).copy(),
                        np.broadcast_to(one.bad, shape).copy())


def check_sensors(
    times: FloatArray, values: FloatArray, grid: tuple[int, int], start: float
) -> SensorHealth:
    """Find faulty temperature sensors and repair their samples.

    Args:
        times: stamp-sorted sample stamps (Nt,) [s].
        values: readings (Nt, S) [degC], one column per sensor (row-major on the grid when
            S is the grid's size).
        grid: the actuator grid (rows, cols).
        start: the record's start on the stamps' time base [s] (findings' spans count from it).

    Returns:
        The findings, the repaired readings (``values`` itself when none) and the bad samples.

    """
    n, S = values.shape
    if S > 1 and n and np.array_equal(values, np.broadcast_to(values[:, :1], values.shape),
                                      equal_nan=True):
        return _single_sensor(times, values, start)
    bad = np.zeros((n, S), dtype=bool)
    found = []
    if n >= 2 * FROZEN_MIN_SAMPLES:
        for first in range(0, S, CHUNK):
            checker = _Checker(times, values[:, first : first + CHUNK], first)
            checker.flat_and_frozen()
            checker.dropouts()
            checker.out_of_range()
            checker.noise_change()  # first: a noisy spell is no jump
            checker.jumps()
            bad[:, first : first + CHUNK] = checker.bad
            found += checker.found
    if not found:
        return SensorHealth([], values, bad)
    fixed, actions = _repair(values, bad, grid)
    findings = []
    for kind, sensor, a, b, value, unit, sentence in sorted(found, key=lambda f: f[1]):
        subject, row, col = _subject(sensor, grid, S)
        findings.append(Finding(
            kind=kind, subject=subject, index=sensor, row=row, col=col,
            start_s=float(times[a] - start), end_s=float(times[min(b, n - 1)] - start),
            value=value, unit=unit,
            sentence=f"Temperature {subject} {sentence} "
                     f"({times[a] - start:.1f}-{times[min(b, n - 1)] - start:.1f} s).",
            action=actions[sensor] or "none",
        ))
    return SensorHealth(findings, fixed, bad)
