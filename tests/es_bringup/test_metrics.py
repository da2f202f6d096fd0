"""Metrics of a closed-loop run on synthetic lockstep data with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from es_bringup.metrics import align_run, period_slots, reduction, run_metrics, setpoint_period

RATE = 100.0  # steps per second
PERIOD = 1.0


def lockstep_run(gain_per_degc: float, steps: int = 2100, grid: tuple[int, int] = (1, 1)):
    """Set point 0-100 nm at 1 Hz; temperature stepped 40 -> 52 degC; output = g(T) * set point.

    The displacement of step k+1 answers the set point of step k (lockstep protocol).
    """
    t = np.arange(steps) / RATE
    sp = 50e-9 * (1.0 - np.cos(2 * np.pi * t / PERIOD))
    # 40, 42, ..., 52 in 7 equal steps of whole periods of the aligned output (from step 1)
    temp = 40.0 + 2.0 * np.floor(np.maximum(t - 1 / RATE, 0) / (steps / RATE / 7.0))
    gain = 1.0 - gain_per_degc * (temp - 46.0)
    setpoint = np.broadcast_to(sp[:, None, None], (steps, *grid)).copy()
    temperature = np.broadcast_to(temp[:, None, None], (steps, *grid)).copy()
    displacement = np.zeros_like(setpoint)
    displacement[1:] = setpoint[:-1] * gain[1:, None, None]
    return t, displacement, setpoint, t, temperature


def test_alignment_pairs_displacement_with_previous_setpoint():
    t, disp, sp, tt, temp = lockstep_run(0.0)
    run = align_run(t, disp, sp, tt, temp)
    assert np.array_equal(run.output, run.setpoint)
    assert run.times.size == t.size - 1
    # one set point fewer than displacements is the same protocol
    run2 = align_run(t, disp, sp[:-1], tt, temp)
    assert np.array_equal(run2.setpoint, run.setpoint)


def test_alignment_rejects_counts_that_break_the_protocol():
    t, disp, sp, tt, temp = lockstep_run(0.0)
    with pytest.raises(ValueError, match="lockstep"):
        align_run(t, disp, sp[:-5], tt, temp)
    with pytest.raises(ValueError, match="shapes"):
        align_run(t, disp, sp[:, :, :1].repeat(2, axis=2), tt, temp)


def test_period_found_from_setpoint_spectrum():
    t, _, sp, _, _ = lockstep_run(0.0)
    assert setpoint_period(t, sp.reshape(len(t), -1)) == pytest.approx(PERIOD, rel=0.01)
    assert setpoint_period(t, np.ones((len(t), 4))) is None


def test_variation_matches_gain_change_and_vanishes_when_compensated():
    slope = 0.03
    t, disp, sp, tt, temp = lockstep_run(slope)
    run = align_run(t, disp, sp, tt, temp)
    metrics, slots = run_metrics(run, PERIOD, skip_s=1.0)
    # mid-range 46 degC is a slot; the farthest slots (40, 52) deviate by 6 * 3 % of 100 nm
    assert metrics.variation_m == pytest.approx(6 * slope * 100e-9, rel=0.02)
    assert np.isclose(slots.temperature[slots.reference_slot[0], 0], 46.0)
    compensated, _ = run_metrics(align_run(*lockstep_run(0.0)), PERIOD, skip_s=1.0)
    assert compensated.variation_m < 1e-15
    assert reduction(compensated.variation_m, metrics.variation_m) == pytest.approx(1.0)
    assert metrics.max_error_m == pytest.approx(6 * slope * 100e-9, rel=0.02)
    assert 0 < metrics.rms_error_m < metrics.max_error_m


def test_ac_variation_ignores_a_constant_offset_per_temperature():
    t, disp, sp, tt, temp = lockstep_run(0.0)
    disp = disp + 1e-9 * (temp - 46.0)  # pure offset, e.g. thermal expansion
    metrics, _ = run_metrics(align_run(t, disp, sp, tt, temp), PERIOD, skip_s=1.0)
    assert metrics.variation_m == pytest.approx(6e-9, rel=0.02)
    assert metrics.ac_variation_m < 1e-15


def test_grid_maps_have_grid_shape_and_locate_the_worst_actuator():
    t, disp, sp, tt, temp = lockstep_run(0.03, grid=(3, 4))
    disp[:, 2, 1] *= 1.5
    metrics, _ = run_metrics(align_run(t, disp, sp, tt, temp), PERIOD, skip_s=1.0)
    assert metrics.rms_error_map.shape == (3, 4)
    worst = np.unravel_index(np.argmax(metrics.rms_error_map), (3, 4))
    assert (int(worst[0]), int(worst[1])) == (2, 1)
    assert metrics.variation_map.shape == (3, 4)


def test_too_short_run_is_a_clear_error():
    t, disp, sp, tt, temp = lockstep_run(0.0, steps=50)
    with pytest.raises(ValueError, match="shorter than one"):
        period_slots(align_run(t, disp, sp, tt, temp), PERIOD)
