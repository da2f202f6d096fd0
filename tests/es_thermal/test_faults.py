"""Sensor fault handling, in the monitor and through the whole estimator (no ROS)."""

from __future__ import annotations

import numpy as np
import pytest

from es_thermal.estimator import EstimatorConfig, SampleClock, TemperatureEstimator
from es_thermal.faults import FaultConfig, SensorFaultMonitor, StaleWatch
from es_thermal.interpolation import actuator_positions, block_centre_positions
from es_thermal.network import NetworkParams

RNG = np.random.default_rng(3)


def noisy(n: int, value: float = 40.0) -> np.ndarray:
    return value + 0.01 * RNG.standard_normal(n)


def test_monitor_classifies_each_fault() -> None:
    mon = SensorFaultMonitor(4, FaultConfig(valid_min=0.0, valid_max=100.0))
    health = mon.check(np.array([40.0, np.nan, np.inf, 150.0]), 0.0)
    assert health.valid.tolist() == [True, False, False, False]
    assert health.counts() == {"valid": 1, "non_finite": 2, "out_of_range": 1, "stuck": 0}
    assert health.excluded_indices().tolist() == [1, 2, 3]
    with pytest.raises(ValueError, match="expected 4"):
        mon.check(np.zeros(5), 0.1)


def test_stuck_after_stuck_time_and_recovers_on_change() -> None:
    cfg = FaultConfig(stuck_time=2.0, stuck_band=1e-3)
    mon = SensorFaultMonitor(2, cfg)
    verdicts = []
    for k in range(40):  # 10 Hz: sensor 1 frozen at 41.0, sensor 0 noisy
        verdicts.append(mon.check(np.array([noisy(1)[0], 41.0]), 0.1 * k).stuck.copy())
    stuck = np.array(verdicts)
    assert not stuck[:, 0].any()
    first = int(np.argmax(stuck[:, 1]))
    assert first == 20  # stuck once 2.0 s passed inside the band
    assert stuck[first:, 1].all()
    assert not mon.check(np.array([40.0, 41.5]), 4.0).stuck[1]  # moved: valid again


def test_non_finite_interrupts_stuck_tracking() -> None:
    mon = SensorFaultMonitor(1, FaultConfig(stuck_time=1.0))
    for k in range(8):
        mon.check(np.array([41.0]), 0.1 * k)
    mon.check(np.array([np.nan]), 0.8)
    # Back at the same value: a fresh band, not stuck until stuck_time passes again.
    assert mon.check(np.array([41.0]), 0.9).valid[0]
    assert mon.check(np.array([41.0]), 1.95).stuck[0]


def test_stale_watch() -> None:
    watch = StaleWatch(2.0)
    assert watch.is_stale(0.0) and not watch.seen
    watch.feed(10.0)
    assert not watch.is_stale(11.9)
    assert watch.is_stale(12.1)
    with pytest.raises(ValueError):
        StaleWatch(0.0)


def test_fault_config_validation() -> None:
    with pytest.raises(ValueError, match="below"):
        FaultConfig(valid_min=50.0, valid_max=10.0)
    with pytest.raises(ValueError):
        FaultConfig(stuck_time=0.0)


@pytest.mark.parametrize("kind", ["model", "lowpass"])
def test_estimator_excludes_bad_sensors_then_loses_all_then_recovers(kind: str) -> None:
    rows = cols = 4
    pos = block_centre_positions(rows, cols, 2)  # 4 sensors
    cfg = EstimatorConfig(
        rows, cols, pos, kind=kind, network=NetworkParams().time_scaled(0.05),
        faults=FaultConfig(stuck_time=1.0, stuck_band=1e-6),
    )
    est = TemperatureEstimator(cfg)
    t = 0.0
    for _ in range(20):
        t += 0.1
        out = est.update(t, noisy(4))
    assert out.temperatures is not None
    np.testing.assert_allclose(out.temperatures, 40.0, atol=0.03)
    # One NaN, one out of range, one stuck: estimate from the last one, still near 40.
    stuck_value = 40.0
    for _ in range(15):
        t += 0.1
        readings = noisy(4)
        readings[0], readings[1], readings[2] = np.nan, 500.0, stuck_value
        out = est.update(t, readings)
    assert out.health.valid.tolist() == [False, False, False, True]
    assert out.health.counts()["stuck"] == 1
    assert out.temperatures is not None and np.all(np.isfinite(out.temperatures))
    np.testing.assert_allclose(out.temperatures, 40.0, atol=0.05)
    # Every sensor dead: no estimate.
    t += 0.1
    out = est.update(t, np.full(4, np.nan))
    assert out.temperatures is None and out.health.valid_count == 0
    assert est.latest is out
    # Sensors return (at a new temperature): estimates resume by themselves.
    for _ in range(5):
        t += 0.1
        out = est.update(t, noisy(4, 40.2))
    assert out.temperatures is not None and np.all(np.isfinite(out.temperatures))
    assert out.health.valid.all()


def test_estimator_rejects_wrong_sizes_without_changing_state() -> None:
    cfg = EstimatorConfig(2, 2, actuator_positions(2, 2), kind="lowpass")
    est = TemperatureEstimator(cfg)
    est.update(0.1, np.full(4, 40.0))
    with pytest.raises(ValueError, match="expected 4"):
        est.update(0.2, np.full(3, 40.0))
    assert est.latest is not None and est.latest.time == pytest.approx(0.1)
    with pytest.raises(ValueError, match="shape"):
        est.set_heat_load(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="NaN"):
        est.set_heat_load(np.array([[0.0, np.nan], [0.0, 0.0]]))


def test_time_running_backwards_restarts_from_readings() -> None:
    cfg = EstimatorConfig(2, 2, actuator_positions(2, 2), kind="model")
    est = TemperatureEstimator(cfg)
    for k in range(10):
        est.update(0.1 * (k + 1), np.full(4, 40.0))
    out = est.update(0.05, np.full(4, 45.0))  # a simulation restarted
    assert out.temperatures is not None
    np.testing.assert_allclose(out.temperatures, 45.0)


def test_config_validation() -> None:
    pos = actuator_positions(2, 2)
    with pytest.raises(ValueError, match="estimator"):
        EstimatorConfig(2, 2, pos, kind="magic")
    with pytest.raises(ValueError, match="positions"):
        EstimatorConfig(2, 2, np.zeros((3,)))
    with pytest.raises(ValueError, match="sample_period"):
        EstimatorConfig(2, 2, pos, sample_period=0.0)


def test_sample_clock_counts_through_jitter_and_follows_gaps() -> None:
    clock = SampleClock(0.1)
    arrivals = [5.0, 5.0, 5.2, 5.3, 5.3, 6.5, 6.6, 1.0]  # jittery clock, gap, restart
    stamps = [clock.stamp(t) for t in arrivals]
    np.testing.assert_allclose(stamps, [5.0, 5.1, 5.2, 5.3, 5.4, 6.5, 6.6, 1.0])
