"""Tracking and temperature-induced variation of a closed-loop run, as the thesis measures it.

Pure numpy (no rclpy): works on arrays read from a bag with ``es_msgs_py.bag.read_bag``.

Alignment follows the lockstep protocol (docs/architecture.md): the command computed for the
set point of step k is applied over [t_k, t_k+1), so the displacement sampled at t_k+1 answers
set point k (see :func:`align_run`).

The temperature-induced variation follows thesis sections 4-1/4-2: cut the output into whole
periods of the set point, average the periods that fall in the same temperature slot
(``slot_width`` degC, 0.2 degC in the thesis), take the averaged period at the slot nearest
the mid-range temperature as the reference, and report the largest deviation of any averaged
period from it. Per actuator; the run's figure is the largest over actuators.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from es_bringup.errors import RunDataError
from es_common.arrays import FloatArray, IndexArray

if TYPE_CHECKING:
    from es_sim_plant.plant import SimulationResult

#: Thesis temperature slot for period averaging (section 4-2), degC.
DEFAULT_SLOT_WIDTH = 0.2
#: An AC component smaller than this (m, standard deviation) has no period to fold on.
_MIN_AC_STD = 1e-12


@dataclass(frozen=True)
class AlignedRun:
    """One run on the displacement time base; A actuators flattened row-major.

    Attributes:
        times: sample times, s, shape (N,).
        setpoint: set point in force for each sample, m, shape (N, A).
        output: displacement, m, shape (N, A).
        temperature: newest temperature estimate at each sample, degC, shape (N, A).
        grid_shape: (R, C) of the actuator grid (R * C == A).

    """

    times: FloatArray
    setpoint: FloatArray
    output: FloatArray
    temperature: FloatArray
    grid_shape: tuple[int, int]

    @property
    def error(self) -> FloatArray:
        """Tracking error output - set point, m, shape (N, A)."""
        return self.output - self.setpoint

    @classmethod
    def of_simulation(cls, result: SimulationResult, dt: float) -> AlignedRun:
        """Return an offline simulation's run, each step's output at the step's end.

        Args:
            result: what :func:`es_sim_plant.plant.simulate` returned (grids (K, R, C)).
            dt: the control step, s (the displacement of step k is read at t_k + dt).

        """
        steps, rows, cols = result.setpoint.shape
        return cls(
            times=result.time + dt,
            setpoint=result.setpoint.reshape(steps, rows * cols),
            output=result.displacement.reshape(steps, rows * cols),
            temperature=result.actuator_temperature.reshape(steps, rows * cols),
            grid_shape=(rows, cols),
        )


@dataclass(frozen=True)
class PeriodSlots:
    """Period-averaged outputs per temperature slot, per actuator.

    Attributes:
        phase: time within a period, s, shape (P,).
        mean_output: averaged period per slot, m, shape (S, A, P); NaN where a slot is empty.
        mean_setpoint: averaged set point period per slot, m, shape (S, A, P).
        temperature: mean temperature of each slot, degC, shape (S, A); NaN where empty.
        reference_slot: index of the reference (mid-range) slot per actuator, shape (A,).
        variation: largest |mean_output - reference| per actuator, m, shape (A,).
        ac_variation: the same with each averaged period's mean removed (the thesis's
            normalisation about the DC set point in section 4-2), m, shape (A,).

    """

    phase: FloatArray
    mean_output: FloatArray
    mean_setpoint: FloatArray
    temperature: FloatArray
    reference_slot: IndexArray
    variation: FloatArray
    ac_variation: FloatArray


@dataclass(frozen=True)
class RunMetrics:
    """Figures of one run (m): what summary.json holds, plus per-actuator maps."""

    variation_m: float
    ac_variation_m: float
    rms_error_m: float
    max_error_m: float
    rms_error_map: FloatArray
    variation_map: FloatArray


def align_run(
    displacement_times: FloatArray,
    displacement: FloatArray,
    setpoint: FloatArray,
    temperature_times: FloatArray,
    temperature: FloatArray,
) -> AlignedRun:
    """Pair every displacement sample with its set point and temperature (module docstring).

    Set points pair by message index, not by bag timestamp: in lockstep step k publishes
    displacement k and then set point k, so displacement k+1 answers set point k. (A
    recorder stamps on reception with its sim clock, which can be one step late or early
    around a step boundary; the index is exact as long as nothing was lost, which the run's
    invariants check.) Temperatures are slow and pair by time: the newest one at or before
    the displacement's timestamp.

    Args:
        displacement_times: bag timestamps of the displacements, s, increasing.
        displacement: displacement grids, m, shape (N, R, C).
        setpoint: set point grids, m, shape (M, R, C) with M = N or N - 1.
        temperature_times: bag timestamps of the temperature estimates, s, increasing.
        temperature: temperature grids, degC, shape (K, R, C).

    Raises:
        RunDataError: grids of different shapes, set point and displacement counts that do
            not fit the lockstep protocol, or no sample left after alignment.

    """
    shapes = {displacement.shape[1:], setpoint.shape[1:], temperature.shape[1:]}
    if len(shapes) != 1 or displacement.ndim != 3:
        raise RunDataError(f"grid shapes differ between topics: {sorted(shapes)}")
    if len(setpoint) not in (len(displacement), len(displacement) - 1):
        raise RunDataError(
            f"{len(displacement)} displacements and {len(setpoint)} set points do not fit "
            "one of each per lockstep step"
        )
    rows, cols = displacement.shape[1:]
    paired = len(setpoint) if len(setpoint) < len(displacement) else len(setpoint) - 1
    out_times = displacement_times[1 : paired + 1]
    t_index = np.searchsorted(temperature_times, out_times, side="right") - 1
    keep = t_index >= 0
    if not np.any(keep):
        raise RunDataError("no displacement sample follows a set point and a temperature")
    flat = rows * cols
    return AlignedRun(
        times=out_times[keep],
        setpoint=setpoint[:paired][keep].reshape(-1, flat),
        output=displacement[1 : paired + 1][keep].reshape(-1, flat),
        temperature=temperature[t_index[keep]].reshape(-1, flat),
        grid_shape=(rows, cols),
    )


def setpoint_period(times: FloatArray, setpoint: FloatArray) -> float | None:
    """Return the period (s) of the set point's dominant AC component, ``None`` if static.

    Uses the actuator with the largest AC content and the highest peak of its spectrum,
    zero-padded 16x so that a run of a few periods still resolves the frequency to a
    fraction of a sample per period; the period is rounded to whole samples.
    """
    ac = setpoint - setpoint.mean(axis=0)
    spread = ac.std(axis=0)
    column = int(np.argmax(spread))
    if spread[column] < _MIN_AC_STD or times.size < 4:
        return None
    dt = float(np.median(np.diff(times)))
    padded = 16 * times.size
    spectrum = np.abs(np.fft.rfft(ac[:, column], n=padded))
    freqs = np.fft.rfftfreq(padded, dt)
    spectrum[freqs < 1.5 / (times.size * dt)] = 0.0  # below 1.5 cycles per run: no period
    peak = int(np.argmax(spectrum))
    if freqs[peak] <= 0 or spectrum[peak] == 0:
        return None
    return round(1.0 / (freqs[peak] * dt)) * dt


class WholePeriods(NamedTuple):
    """Where a run's whole set-point periods lie.

    ``periods`` periods of ``samples`` samples each from index ``start``, ``dt`` [s] apart.
    """

    dt: float
    samples: int
    start: int
    periods: int


def whole_periods(run: AlignedRun, period_s: float, skip_s: float = 0.0) -> WholePeriods:
    """Return the whole periods of ``period_s`` in ``run`` after ``skip_s`` (maybe none)."""
    dt = float(np.median(np.diff(run.times))) if run.times.size > 1 else period_s
    samples = round(period_s / dt)
    start = int(np.searchsorted(run.times, run.times[0] + skip_s))
    count = (run.times.size - start) // samples if samples > 0 else 0
    return WholePeriods(dt, samples, start, count)


def period_slots(
    run: AlignedRun,
    period_s: float,
    slot_width: float = DEFAULT_SLOT_WIDTH,
    skip_s: float = 0.0,
) -> PeriodSlots:
    """Average whole periods of the output per temperature slot (module docstring).

    Args:
        run: the aligned run.
        period_s: period of the set point, s.
        slot_width: width of a temperature slot, degC.
        skip_s: start-up time left out before the first period, s.

    Raises:
        RunDataError: fewer than one whole period after ``skip_s``, or a bad period/slot width.

    """
    if not (period_s > 0 and slot_width > 0):
        raise RunDataError(f"period ({period_s}) and slot width ({slot_width}) must be > 0")
    dt, samples, start, count = whole_periods(run, period_s, skip_s)
    if count < 1:
        raise RunDataError(f"run shorter than one {period_s:g} s period after {skip_s:g} s")
    stop = start + count * samples
    actuators = run.output.shape[1]

    def periods(values: FloatArray) -> FloatArray:  # (count, samples, A) -> (count, A, samples)
        return values[start:stop].reshape(count, samples, actuators).transpose(0, 2, 1)

    output, setpoint = periods(run.output), periods(run.setpoint)
    period_temp = periods(run.temperature).mean(axis=2)  # (count, A)
    low = period_temp.min(axis=0)
    slot = np.floor((period_temp - low) / slot_width).astype(np.intp)  # (count, A)
    slots = int(slot.max()) + 1
    column = np.broadcast_to(np.arange(actuators), slot.shape)
    hits = np.zeros((slots, actuators))
    sum_out = np.zeros((slots, actuators, samples))
    sum_sp = np.zeros_like(sum_out)
    sum_temp = np.zeros((slots, actuators))
    np.add.at(hits, (slot, column), 1.0)
    np.add.at(sum_out, (slot, column), output)
    np.add.at(sum_sp, (slot, column), setpoint)
    np.add.at(sum_temp, (slot, column), period_temp)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_out = sum_out / hits[..., None]
        mean_sp = sum_sp / hits[..., None]
        mean_temp = sum_temp / hits
    middle = 0.5 * (period_temp.min(axis=0) + period_temp.max(axis=0))
    distance = np.where(hits > 0, np.abs(mean_temp - middle), np.inf)
    reference = np.argmin(distance, axis=0)
    ref_out = mean_out[reference, np.arange(actuators)]  # (A, samples)
    deviation = np.abs(mean_out - ref_out[None])
    ac_out = mean_out - mean_out.mean(axis=2, keepdims=True)
    ac_deviation = np.abs(ac_out - ac_out[reference, np.arange(actuators)][None])
    return PeriodSlots(
        phase=np.arange(samples, dtype=np.float64) * dt,
        mean_output=mean_out,
        mean_setpoint=mean_sp,
        temperature=mean_temp,
        reference_slot=reference,
        variation=np.nanmax(deviation, axis=(0, 2)),
        ac_variation=np.nanmax(ac_deviation, axis=(0, 2)),
    )


def run_metrics(
    run: AlignedRun,
    period_s: float,
    slot_width: float = DEFAULT_SLOT_WIDTH,
    skip_s: float = 0.0,
) -> tuple[RunMetrics, PeriodSlots]:
    """Return the run's figures and its period slots; errors count from ``skip_s`` on."""
    slots = period_slots(run, period_s, slot_width, skip_s)
    after = run.times >= run.times[0] + skip_s
    error = run.error[after]
    rms_map = np.sqrt(np.mean(error**2, axis=0))
    metrics = RunMetrics(
        variation_m=float(slots.variation.max()),
        ac_variation_m=float(slots.ac_variation.max()),
        rms_error_m=float(np.sqrt(np.mean(error**2))),
        max_error_m=float(np.max(np.abs(error))),
        rms_error_map=rms_map.reshape(run.grid_shape),
        variation_map=slots.variation.reshape(run.grid_shape),
    )
    return metrics, slots


def reduction(variation_m: float, baseline_variation_m: float) -> float:
    """Fractional reduction of a variation against the uncompensated baseline (1 = all gone)."""
    if baseline_variation_m <= 0:
        return float("nan")
    return 1.0 - variation_m / baseline_variation_m
