"""Align measured topics on the bag's time base and split them into training and held-out data.

The displacement stamps are the sample grid (the measured output). The command is a
zero-order hold: each displacement sample sees the last command stamped before it (when stamps
coincide, as in a lock-step simulation, whether "before" includes the same stamp is decided
from the data, see search/state.py). The temperature, usually slower, is linearly interpolated onto
the displacement stamps; its derivative is a Savitzky-Golay slope over ``RATE_WINDOW_S`` on a
uniform resampling of the temperature. Nothing is extrapolated: samples before the first
command, and those before the first or after the last temperature message, are dropped. NaN
values are dropped per actuator and counted, never propagated. Gaps in any topic are found
and the samples they would need are removed and counted (gaps.py): nothing is interpolated
across a gap. The samples whose input could read an actuator's command at an edge its
samples cannot resolve (edges.py) are masked for that actuator only (:attr:`AlignedData.edge_mask`,
applied where rows are chosen for a fit or a score), the same pairs for every model.

Training and held-out data are interleaved time blocks (even blocks train, odd blocks are
held out), so that the held-out score tests interpolation across the run, not extrapolation.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Final

import numpy as np
from scipy.signal import savgol_filter

from es_calibration.data.edges import EdgeExclusion, EdgeMask, account, edge_mask
from es_calibration.data.gaps import (
    GAP_FACTOR,
    Gap,
    TemperatureSpan,
    exclude,
    exclude_outside_span,
    find_gaps,
)
from es_calibration.data.stamps import repeated, run_lengths, spread_repeated
from es_calibration.data.timing import late_burst_messages
from es_calibration.errors import CalibrationInputError
from es_common.arrays import BoolArray, FloatArray, IndexArray

# The contract's topic names (es_msgs_py.topics imports rclpy; this tool must not need it).
COMMAND: Final = "/dm/command"
DISPLACEMENT: Final = "/dm/displacement"
TEMPERATURE: Final = "/dm/temperature"
TEMPERATURE_RAW: Final = "/dm/temperature/raw"

#: Fewest usable displacement samples (after dropping NaN) for a calibration.
MIN_SAMPLES: Final = 200
#: Shortest usable record [s].
MIN_DURATION_S: Final = 2.0
#: Window of the temperature-rate estimate [s] (the thermal disturbance is slower than 0.1 Hz).
RATE_WINDOW_S: Final = 2.0
#: Key of :attr:`AlignedData.dropped` for samples with ambiguous stamps (see data/stamps.py).
AMBIGUOUS: Final = "displacement with ambiguous repeated stamp"
#: Keys of :attr:`AlignedData.dropped` for samples that gaps take out, by role (gaps.py).
GAP_DROPS: Final = {
    "temperature": "displacement needing temperature from a gap",
    "command": "displacement in or after a command hole",
}
#: Key of :attr:`AlignedData.dropped` for samples outside the temperature topic's span.
SPAN_DROPS: Final = "displacement outside the temperature record"
#: Key of :attr:`AlignedData.dropped` for displacement samples delivered in a late burst.
LATE_BURST_DROPS: Final = "displacement in a late burst"
#: Actuators resampled at once by :func:`resample_temperature` (bounds its temporaries).
RESAMPLE_COLUMNS: Final = 512
#: Number of interleaved blocks for long records, and the shortest block [s].
MAX_BLOCKS: Final = 16
MIN_BLOCK_S: Final = 1.0


@dataclass(frozen=True)
class MeasuredData:
    """Topic series of one measured run (times in s on the bag's time base).

    Attributes:
        command_times, command: (Nc,), (Nc, R, C) [V].
        displacement_times, displacement: (Nd,), (Nd, R, C) [m].
        temperature_times, temperature: (Nt,), (Nt, R, C) [degC], on the actuator grid.
        temperature_source: topic the temperature came from.

    """

    command_times: FloatArray
    command: FloatArray
    displacement_times: FloatArray
    displacement: FloatArray
    temperature_times: FloatArray
    temperature: FloatArray
    temperature_source: str = TEMPERATURE


@dataclass
class AlignedData:
    """Topics on the displacement time base (time-major, actuators flattened row-major).

    Attributes:
        grid: (rows, cols).
        start_time: bag time of the first kept displacement sample [s].
        t: sample times since ``start_time`` (N,) [s].
        displacement: (N, A) [m]; ``valid`` (N, A) marks finite displacements (a sample also
            needs a finite command in effect, checked where the sample is used).
        command_times: (Nc,) since ``start_time``; ``command`` (Nc, A), NaN held from the last
            finite value (for the play operator); ``command_finite`` (Nc, A).
        temperature_times: uniform (Nt,) since ``start_time``; ``temperature`` and
            ``temperature_rate`` (Nt, A) [degC, degC/s].
        train: (N,) True for training samples; ``block_edges`` the block boundaries [s].
        dropped: counts of dropped values by reason.
        include_same_stamp: whether a command stamped exactly at a sample is already in effect.
        repeated_stamps: how repeated stamps were resolved ("" when none repeat).
        gaps: gaps found in any topic, in time order, with the samples each excluded.
        sample_index: (N,) position of each sample in the stamp-sorted displacement series
            it was aligned from (what a streamed recording gathers by).
        grid_mean_temperature: the whole grid's mean temperature [degC] when this holds
            only some actuators' columns (None: the mean of ``temperature``).
        command_period_s: the command period [s] when ``command_times`` holds only some
            commands (None: their median spacing).
        command_edges: what unresolvable command edges take out of the (sample, actuator)
            pairs (edges.py; None: the rule was not applied).
        edge_mask: the per-actuator edges (edges.py; its times on this time base).
        columns: the grid (row-major) index of each actuator column (None: the columns are
            the grid's first ones in order), what ``edge_mask`` names actuators by.
        recorded_samples: displacement messages of the recording before any was dropped.
        stamp_jitter_s: the displacement stamps' receive jitter [s rms] (timing.py; 0 when
            they are sampling times or it was not measured).
        temperature_span: what the ends of the temperature topic took out (gaps.py; None:
            the rule was not applied).

    """

    grid: tuple[int, int]
    start_time: float
    t: FloatArray
    displacement: FloatArray
    valid: BoolArray
    command_times: FloatArray
    command: FloatArray
    command_finite: BoolArray
    temperature_times: FloatArray
    temperature: FloatArray
    temperature_rate: FloatArray
    train: BoolArray
    block_edges: FloatArray
    temperature_source: str
    dropped: dict[str, int] = field(default_factory=dict)
    include_same_stamp: bool = True
    repeated_stamps: str = ""
    gaps: list[Gap] = field(default_factory=list)
    sample_index: IndexArray = field(default_factory=lambda: np.zeros(0, np.intp))
    grid_mean_temperature: float | None = None
    command_period_s: float | None = None
    command_edges: EdgeExclusion | None = None
    temperature_span: TemperatureSpan | None = None
    edge_mask: EdgeMask = field(default_factory=EdgeMask.empty)
    columns: IndexArray | None = None
    recorded_samples: int = 0
    stamp_jitter_s: float = 0.0

    @property
    def command_finite_all(self) -> bool:
        """Return whether every command value was finite."""
        return self.dropped.get("command NaN", 0) == 0

    @property
    def n_actuators(self) -> int:
        """Return R*C."""
        return self.grid[0] * self.grid[1]

    @cached_property
    def sample_rate(self) -> float:
        """Return the median displacement sample rate [Hz]."""
        return float(1.0 / np.median(np.diff(self.t)))

    @cached_property
    def command_period(self) -> float:
        """Return the command period [s]: the mean of the steps within 10 % of the median.

        The mean, not the median: stamps rounded to a float's resolution quantise each step,
        and a shift of many periods must not add up that rounding. A streamed recording
        gives it (``command_period_s``) from the whole run's stamps.
        """
        if self.command_period_s is not None:
            return self.command_period_s
        steps = np.diff(self.command_times)
        median = float(np.median(steps))
        return float(np.mean(steps[np.abs(steps - median) <= 0.1 * median]))

    @cached_property
    def mean_temperature(self) -> float:
        """Return the mean temperature over the record and actuators [degC]."""
        if self.grid_mean_temperature is not None:
            return self.grid_mean_temperature
        return float(np.mean(self.temperature))

    @property
    def stamp_tolerance(self) -> float:
        """Return the distance [s] below which two stamps count as the same instant."""
        return 1e-2 * self.command_period

    @property
    def has_same_stamps(self) -> bool:
        """Return whether some command stamps coincide with displacement stamps."""
        pos = np.clip(np.searchsorted(self.command_times, self.t), 1, self.command_times.size - 1)
        nearest = np.minimum(
            np.abs(self.t - self.command_times[pos - 1]), np.abs(self.t - self.command_times[pos])
        )
        return bool(np.any(nearest < self.stamp_tolerance))

    def command_index(self, rows: IndexArray, delay_s: float = 0.0) -> IndexArray:
        """Return the index of the command in effect at samples ``rows``, ``delay_s`` earlier.

        -1 where no command was in effect yet. Stamps closer than ``stamp_tolerance`` count as
        equal (float round-off of recorded stamps must not decide which command applies).
        """
        tol = self.stamp_tolerance
        when = self.t[rows] - delay_s + (tol if self.include_same_stamp else -tol)
        return np.searchsorted(self.command_times, when, side="right") - 1

    def edge_excluded(self, rows: IndexArray, actuators: IndexArray) -> BoolArray:
        """Return (len(actuators), len(rows)): the pairs an unresolvable command edge takes out.

        ``actuators`` are column indices of this data (see ``columns``).
        """
        named = actuators if self.columns is None else self.columns[actuators]
        return self.edge_mask.excluded(self.t[rows], np.asarray(named, np.intp))

    def kept_fraction(self) -> float:
        """Return the share of the recording's (sample, actuator) pairs kept for the fit.

        Kept: a finite displacement that no gap, end of the temperature record, ambiguous
        stamp or unresolvable command edge of the actuator's own took out (this data's
        actuators; a finite command in effect is checked where the sample is used).
        """
        rows = np.arange(self.t.size, dtype=np.intp)
        kept = 0
        for lo in range(0, self.displacement.shape[1], RESAMPLE_COLUMNS):
            cols = np.arange(lo, min(lo + RESAMPLE_COLUMNS, self.displacement.shape[1]),
                             dtype=np.intp)
            kept += int((self.valid[:, cols].T & ~self.edge_excluded(rows, cols)).sum())
        total = max(self.recorded_samples, self.t.size) * self.displacement.shape[1]
        return kept / max(total, 1)

    def linked(self, rows: IndexArray) -> BoolArray:
        """Return (len(rows) - 1,): whether consecutive ``rows`` are neighbours in time.

        Neighbours are consecutive samples with no gap (removed samples) between them.
        """
        step = np.diff(self.t[rows])
        return np.asarray((np.diff(rows) == 1) & (step < GAP_FACTOR / self.sample_rate))

    def interpolation(self, rows: IndexArray) -> tuple[IndexArray, FloatArray]:
        """Return (lower index, weight of the upper) of the temperature at samples ``rows``."""
        times = self.temperature_times
        pos = np.clip(np.searchsorted(times, self.t[rows], side="right") - 1, 0, len(times) - 2)
        w = np.clip((self.t[rows] - times[pos]) / (times[pos + 1] - times[pos]), 0.0, 1.0)
        return pos, w

    def temperature_at(self, rows: IndexArray, actuators: IndexArray) -> FloatArray:
        """Return the temperature (A, n) at samples ``rows`` for ``actuators``."""
        return self._interpolate(self.temperature, rows, actuators)

    def temperature_rate_at(self, rows: IndexArray, actuators: IndexArray) -> FloatArray:
        """Return dT/dt (A, n) at samples ``rows`` for ``actuators``."""
        return self._interpolate(self.temperature_rate, rows, actuators)

    def _interpolate(
        self, series: FloatArray, rows: IndexArray, actuators: IndexArray
    ) -> FloatArray:
        pos, w = self.interpolation(rows)
        sub = series[:, actuators]
        return np.asarray((sub[pos] * (1.0 - w[:, None]) + sub[pos + 1] * w[:, None]).T)


def _fill_nan_columns(times: FloatArray, values: FloatArray) -> FloatArray:
    """Interpolate each column over its NaN entries (columns without NaN are untouched)."""
    out = values.copy()
    bad = ~np.isfinite(out)
    for col in np.flatnonzero(bad.any(axis=0)):  # only columns that had NaN: the rare path
        good = ~bad[:, col]
        if good.sum() < 2:
            raise CalibrationInputError(
                f"temperature of actuator {col} has fewer than 2 finite samples"
            )
        out[:, col] = np.interp(times, times[good], out[good, col])
    return out


def _check_series(name: str, times: FloatArray, values: FloatArray, grid: tuple[int, ...]) -> None:
    if values.ndim != 3 or values.shape[0] != times.shape[0]:
        raise CalibrationInputError(f"{name}: expected (N, rows, cols) samples, got {values.shape}")
    if values.shape[1:] != grid:
        raise CalibrationInputError(
            f"mismatched grid sizes: {name} is {values.shape[1]} x {values.shape[2]}, "
            f"displacement is {grid[0]} x {grid[1]}"
        )
    if times.size < 2:
        raise CalibrationInputError(f"{name}: too short to fit ({times.size} messages)")
    if np.any(np.diff(times) < 0):
        raise CalibrationInputError(f"{name}: time stamps go backwards")


def _resolve_repeated_stamps(
    data: MeasuredData,
) -> tuple[MeasuredData, dict[str, int], str, IndexArray | None]:
    """Apply the rules of data/stamps.py to ``data`` (each series sorted by time).

    Returns the data to align, counts of dropped samples, a one-line account of what was
    done ("" when no stamp repeats) and the displacement samples kept (None: all).
    """
    counts: dict[str, int] = {}
    notes: list[str] = []
    out = data
    n_temp = int(repeated(data.temperature_times).sum())
    if n_temp:
        out = replace(out, temperature_times=temperature_stamps(data.temperature_times))
        notes.append(
            f"{n_temp} of {data.temperature_times.size} temperature stamps repeated, spread up "
            "to the next stamp"
        )
    cmd_rep = repeated(data.command_times)
    disp_rep = repeated(data.displacement_times)
    n_cmd, n_disp = int(cmd_rep.sum()), int(disp_rep.sum())
    if n_cmd == 0 and n_disp == 0:
        return out, counts, "; ".join(notes), None
    share = (
        f"repeated stamps: {n_cmd} of {cmd_rep.size} commands, "
        f"{n_disp} of {disp_rep.size} displacements"
    )
    if data.command_times.size == data.displacement_times.size:
        t = spread_repeated(data.displacement_times)
        previous = np.concatenate([[2.0 * t[0] - t[1]], t[:-1]])
        out = replace(out, displacement_times=t, command_times=0.5 * (previous + t))
        notes.append(f"{share}; paired by message order (displacement i answers command i)")
        return out, counts, "; ".join(notes), None
    # time-based pairing: a displacement is ambiguous when its stamp repeats among the
    # displacements, or when the command in effect (either same-stamp convention) is one of
    # a run of commands sharing a stamp (their true times lie anywhere up to the next stamp)
    disp_times = data.displacement_times
    shared = disp_rep.copy()
    shared[:-1] |= disp_rep[1:]
    run_size = run_lengths(data.command_times)
    ambiguous = shared
    for side in ("left", "right"):
        in_effect = np.searchsorted(data.command_times, disp_times, side=side) - 1
        ambiguous |= (in_effect >= 0) & (run_size[np.maximum(in_effect, 0)] > 1)
    counts[AMBIGUOUS] = int(ambiguous.sum())
    keep = ~ambiguous
    if keep.sum() < MIN_SAMPLES:
        raise CalibrationInputError(
            f"too little usable data: {counts[AMBIGUOUS]} of {keep.size} displacement samples "
            f"have an ambiguous repeated stamp and {data.command_times.size} commands cannot be "
            f"paired by order with {keep.size} displacements (need {MIN_SAMPLES} usable samples)"
        )
    out = replace(out, displacement_times=disp_times[keep], displacement=data.displacement[keep])
    notes.append(
        f"{share}; counts differ, so paired by time and {counts[AMBIGUOUS]} ambiguous "
        "displacement samples dropped"
    )
    return out, counts, "; ".join(notes), np.flatnonzero(keep)


def resample_temperature(
    times: FloatArray, values: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, int]:
    """Return the temperature on a uniform time base, its rate, and the NaN values filled.

    ``times`` (Nt,) [s] are strictly increasing (repeated stamps spread), ``values`` (Nt, A)
    [degC]; NaN values are interpolated per actuator. Returns the uniform times (Nu,), the
    temperature and its Savitzky-Golay slope (Nu, A) [degC, degC/s] and the NaN count.

    Raises:
        CalibrationInputError: an actuator has fewer than 2 finite temperatures.

    """
    t_period = float(np.median(np.diff(times)))  # > 0: repeated stamps were spread
    n_uniform = int(np.floor((times[-1] - times[0]) / t_period)) + 1
    uniform = times[0] + t_period * np.arange(max(n_uniform, 2))
    pos = np.clip(np.searchsorted(times, uniform, side="right") - 1, 0, len(times) - 2)
    w = np.clip((uniform - times[pos]) / np.maximum(np.diff(times)[pos], 1e-12), 0, 1)[:, None]
    window = _rate_window(t_period)
    temp_u = np.empty((uniform.size, values.shape[1]))
    rate = np.empty_like(temp_u)
    nan = 0
    # in blocks of actuators: a whole grid's temporaries would be several times its size
    for lo in range(0, values.shape[1], RESAMPLE_COLUMNS):
        cols = slice(lo, lo + RESAMPLE_COLUMNS)
        block = values[:, cols]
        bad = int((~np.isfinite(block)).sum())
        nan += bad
        temp = _fill_nan_columns(times, block) if bad else block
        temp_u[:, cols] = temp[pos] * (1.0 - w) + temp[pos + 1] * w
        if window <= temp_u.shape[0]:
            rate[:, cols] = savgol_filter(
                temp_u[:, cols], window, 2, deriv=1, delta=t_period, axis=0
            )
        else:
            rate[:, cols] = np.gradient(temp_u[:, cols], t_period, axis=0)
    return uniform, temp_u, rate, nan


def temperature_stamps(times: FloatArray) -> FloatArray:
    """Return temperature stamps with runs of repeated stamps spread (data/stamps.py)."""
    return spread_repeated(times) if repeated(times).any() else times


def _rate_window(period: float) -> int:
    """Return the Savitzky-Golay window [samples] of the temperature rate at ``period`` [s]."""
    return max(round(RATE_WINDOW_S / period) | 1, 5)


def _all_gaps(data: MeasuredData) -> list[Gap]:
    """Return the gaps of every topic of ``data`` (stamps sorted), in time order."""
    record = (float(data.displacement_times[0]), float(data.displacement_times[-1]))
    gaps = [
        *find_gaps(COMMAND, "command", data.command_times, record),
        *find_gaps(DISPLACEMENT, "displacement", data.displacement_times),
        *find_gaps(data.temperature_source, "temperature", data.temperature_times, record),
    ]
    return sorted(gaps, key=lambda g: g.start_s)


def align(data: MeasuredData, n_blocks: int | None = None) -> AlignedData:
    """Align ``data`` on the displacement stamps and split it; raise CalibrationInputError."""
    grid = tuple(int(s) for s in data.displacement.shape[1:])
    if len(grid) != 2:
        raise CalibrationInputError(f"displacement: expected a grid, got shape {grid}")
    rows_cols = (grid[0], grid[1])
    for name, times, values in (
        ("displacement", data.displacement_times, data.displacement),
        ("command", data.command_times, data.command),
        ("temperature", data.temperature_times, data.temperature),
    ):
        _check_series(name, times, values, rows_cols)
        if times[-1] == times[0]:
            raise CalibrationInputError(f"{name}: all {times.size} messages share one time stamp")
    gaps = _all_gaps(data)
    recorded = int(data.displacement_times.size)
    data, dropped, stamp_note, index = _resolve_repeated_stamps(data)
    if index is None:
        index = np.arange(data.displacement_times.size)
    A = rows_cols[0] * rows_cols[1]

    # samples before the first command have no known input: drop them
    # stamps are sorted: the kept samples are a suffix (a view, no copy of a large record)
    first = int(np.searchsorted(data.displacement_times, data.command_times[0], side="right"))
    dropped["displacement before first command"] = first
    t_abs = data.displacement_times[first:]
    z = data.displacement[first:].reshape(-1, A)
    index = index[first:]
    # samples delivered in a late burst were sampled at unknown times (timing.py): they go
    late = late_burst_messages(data.displacement_times)[first:]
    if late.any():
        dropped[LATE_BURST_DROPS] = int(late.sum())
        t_abs, z, index = t_abs[~late], z[~late], index[~late]
    cmd = data.command.reshape(-1, A)
    cmd_finite = np.isfinite(cmd)
    dropped["command NaN"] = int((~cmd_finite).sum())
    if (~cmd_finite).any():
        # hold the last finite value so the play operator's state survives a bad message
        idx = np.where(cmd_finite, np.arange(cmd.shape[0])[:, None], 0)
        np.maximum.accumulate(idx, axis=0, out=idx)
        cmd = np.where(cmd_finite.any(axis=0), cmd[idx, np.arange(A)], 0.0)
        cmd = np.where(np.isfinite(cmd), cmd, 0.0)
    if gaps:
        # samples that would need data from a gap go (gaps.py); this copies the kept rows
        t_period = float(np.median(np.diff(data.temperature_times)))
        out, counts, gaps = exclude(t_abs, gaps, (_rate_window(t_period) // 2) * t_period)
        dropped.update({GAP_DROPS[role]: n for role, n in counts.items()})
        t_abs, z, index = t_abs[~out], z[~out], index[~out]
    # samples whose temperature would be extrapolated beyond the topic's ends go (gaps.py)
    out, span = exclude_outside_span(t_abs, data.temperature_times)
    if span.excluded_samples:
        dropped[SPAN_DROPS] = span.excluded_samples
        t_abs, z, index = t_abs[~out], z[~out], index[~out]
    # pairs whose input the actuator's commands cannot resolve are masked (edges.py)
    per_actuator_edges = edge_mask(data.command_times, cmd)
    edge_account = account(per_actuator_edges, t_abs, A)
    if t_abs.size < MIN_SAMPLES:
        raise CalibrationInputError(
            f"too short to fit: {t_abs.size} displacement samples after the first command "
            f"(need {MIN_SAMPLES})"
            + "".join(f"; {n} removed: {key}" for key, n in dropped.items() if n)
        )
    start = float(t_abs[0])
    z_finite = np.isfinite(z)
    dropped["displacement NaN"] = int((~z_finite).sum())


    temp_times = data.temperature_times - start
    uniform, temp_u, rate, dropped["temperature NaN"] = resample_temperature(
        temp_times, data.temperature.reshape(-1, A)
    )

    t = t_abs - start
    duration = float(t[-1])
    if duration < MIN_DURATION_S:
        raise CalibrationInputError(
            f"too short to fit: {duration:.2f} s of data (need {MIN_DURATION_S} s)"
        )
    if n_blocks is None:
        n_blocks = int(np.clip(duration / MIN_BLOCK_S, 4, MAX_BLOCKS)) // 2 * 2
    edges = np.linspace(0.0, duration, n_blocks + 1)
    block = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_blocks - 1)
    train = block % 2 == 0

    valid = z_finite.copy()
    aligned = AlignedData(
        grid=rows_cols,
        start_time=start,
        t=t,
        displacement=z,
        valid=valid,
        command_times=data.command_times - start,
        command=np.asarray(cmd, np.float64),
        command_finite=cmd_finite,
        temperature_times=uniform,
        temperature=temp_u,
        temperature_rate=np.asarray(rate, np.float64),
        train=train,
        block_edges=edges,
        temperature_source=data.temperature_source,
        dropped=dropped,
        repeated_stamps=stamp_note,
        gaps=gaps,
        sample_index=index,
        command_edges=edge_account,
        temperature_span=span,
        edge_mask=per_actuator_edges.shifted(start),
        recorded_samples=recorded,
    )
    usable = valid.sum(axis=0) - np.asarray(edge_account.per_actuator_excluded)
    if usable.min() < MIN_SAMPLES:
        worst = int(np.argmin(usable))
        raise CalibrationInputError(
            f"too short to fit: actuator {worst} has {int(usable[worst])} usable "
            f"samples (need {MIN_SAMPLES})"
        )
    return aligned


def select_rows(mask: BoolArray, max_rows: int) -> IndexArray:
    """Return the indices where ``mask`` holds, thinned by a uniform stride to <= max_rows."""
    rows = np.flatnonzero(mask)
    stride = max(1, int(np.ceil(rows.size / max_rows)))
    return rows[::stride]
