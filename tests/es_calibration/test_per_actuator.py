"""Per-actuator parameters: taken only where held-out scoring says they pay off.

Data written here with numpy (the law and a first-order sensor lag written out, no
es_physics forward model): a 2 x 3 grid whose sensors lag their actuators by different
time constants must get one tau per actuator, within a few sigma of each; the same grid
with one lag for all must keep one value for the grid.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from es_calibration.data.align import MeasuredData
from es_calibration.output.schema import calibration_document
from es_calibration.pipeline import Calibration, calibrate
from es_calibration.search.local import STEP

from .test_combined import law

RATE = 100.0
NOISE = 0.3e-9
SHAPE = (2, 3)


def stand(taus: np.ndarray, seed: int = 7) -> MeasuredData:
    """60 s at 100 Hz: multi-sine drives, actuators swinging 42..50 degC, lagging sensors."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 1.0 / RATE)
    A = taus.size
    phase = rng.uniform(0, 2 * np.pi, (1, A))
    V = (
        150.0
        + 70.0 * np.sin(2 * np.pi * 0.9 * t[:, None] + phase)
        + 50.0 * np.sin(2 * np.pi * 2.3 * t[:, None] + 2 * phase)
    )
    T_a = 46.0 - 4.0 * np.cos(2 * np.pi * t / 20.0)[:, None] + 0.3 * rng.standard_normal((1, A))
    T_s = np.empty_like(T_a)
    for i, tau in enumerate(taus):  # each sensor's exact lag of its actuator (held steps)
        decay = np.exp(-1.0 / (RATE * tau))
        T_s[:, i] = lfilter([1 - decay], [1, -decay], T_a[:, i], zi=[decay * T_a[0, i]])[0]
    z = law(V, T_a) + NOISE * rng.standard_normal(V.shape)
    grid = lambda x: x.reshape(-1, *SHAPE)  # noqa: E731
    return MeasuredData(t, grid(V), t + 0.001, grid(z), t[::10], grid(T_s[::10]))


def _lag(cal: Calibration) -> dict:
    doc = calibration_document(cal)
    (lag,) = [e for e in doc["effects"] if e["name"] == "sensor_lag"]
    return lag


@pytest.mark.slow
def test_different_sensor_lags_get_one_tau_per_actuator() -> None:
    taus = np.array([1.0, 2.0, 3.0, 1.5, 2.5, 4.0])
    cal = calibrate(stand(taus))
    assert [e.name for e in cal.effects] == ["sensor_lag"]
    lag = _lag(cal)
    fitted = np.array(lag["per_actuator"]["tau_s"])
    sigma = np.array(lag["per_actuator_uncertainties"]["tau_s"])
    assert np.all(sigma > 0) and np.all(sigma < 0.2 * taus)
    assert np.all(np.abs(fitted - taus) < 5 * sigma), (fitted, sigma)
    assert lag["parameters"]["tau_s"] == pytest.approx(float(np.median(fitted)))
    (record,) = [r for r in cal.rounds if r.step == STEP]
    assert record.added == "sensor_lag.tau_s per actuator"
    assert cal.final.heldout_rms < 1.2 * NOISE


@pytest.mark.slow
def test_one_sensor_lag_for_all_keeps_one_value_for_the_grid() -> None:
    taus = np.full(6, 2.5)
    cal = calibrate(stand(taus))
    assert [e.name for e in cal.effects] == ["sensor_lag"]
    lag = _lag(cal)
    assert lag["per_actuator"] == {}
    # the lag's own discretisation here (held steps, 10 Hz sensor) biases it by < 1 %
    assert lag["parameters"]["tau_s"] == pytest.approx(2.5, rel=0.01)
    (record,) = [r for r in cal.rounds if r.step == STEP]
    assert record.added is None
    assert "one value for the grid" in record.scores[0].reason
