"""Two effects at once, on data written here with numpy (no es_physics forward model)."""

from __future__ import annotations

import numpy as np
import pytest

from es_calibration.data.align import MeasuredData
from es_calibration.output.schema import calibration_document
from es_calibration.pipeline import calibrate

RATE = 100.0
NOISE = 0.3e-9


def law(V: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The thesis's hyperbolic law with its linear M(T*), k(T*), written out."""
    Ts = T - 38.0
    M = 1504e-18 - 41.5e-18 * Ts
    k = 1167.5e-9 - 17.375e-9 * Ts
    L = 0.2e-3
    return M * L / k**2 * np.tanh(k * V / L) ** 2


def stand(delay_samples: int = 0, alpha: float = 0.0, seed: int = 3) -> MeasuredData:
    """A 1 x 1 test stand at 100 Hz for 90 s: multi-sine drive, temperature 42 -> 50 degC."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 90.0, 1.0 / RATE)
    V = 150.0 + 70.0 * np.sin(2 * np.pi * 0.9 * t) + 50.0 * np.sin(2 * np.pi * 2.3 * t + 1.0)
    T = 46.0 - 4.0 * np.cos(2 * np.pi * t / 90.0)
    applied = np.concatenate([np.full(delay_samples, V[0]), V[: V.size - delay_samples]])
    z = law(applied, T) + alpha * (T - 44.0) + NOISE * rng.standard_normal(t.size)
    grid = lambda x: x[:, None, None]  # noqa: E731
    return MeasuredData(t, grid(V), t + 0.001, grid(z), t[::10], grid(T[::10]))


@pytest.mark.slow
def test_two_effects_are_found_together_with_shares_that_add_up() -> None:
    cal = calibrate(stand(delay_samples=3, alpha=0.4e-9))
    names = sorted(e.name for e in cal.effects)
    assert names == ["delay", "thermal_expansion"], cal.rounds
    found = {e.name: e.parameters for e in cal.effects}
    assert abs(found["delay"]["delay_s"] - 0.03) <= 1.0 / RATE
    assert found["thermal_expansion"]["alpha_m_per_degc"] == pytest.approx(0.4e-9, rel=0.1)
    assert sum(e.share for e in cal.effects) == pytest.approx(1.0, abs=1e-9)
    assert all(e.share > 0.0 for e in cal.effects)
    assert cal.final.heldout_rms <= 1.2 * NOISE
    doc = calibration_document(cal)
    assert doc["schema_version"] == 3
    assert [e["share"] for e in doc["effects"]] == [e.share for e in cal.effects]
    steps = {c["step"] for r in doc["candidates"] for c in r}
    # two effects: the backward check ran; then both were refitted on each half of the record
    assert steps == {"forward", "backward", "halves"}
    assert all(c["accepted"] for r in doc["candidates"] for c in r if c["step"] == "halves")
    backward = [r for r in cal.rounds if r.step == "backward"]
    assert backward[-1].removed is None
    assert all(s.accepted for s in backward[-1].scores)


@pytest.mark.slow
def test_clean_stand_gets_no_effect() -> None:
    cal = calibrate(stand(seed=11))
    assert cal.effects == []
    assert all(r.step == "forward" for r in cal.rounds)


def fractional_stand(delay_periods: float, rate: float, seed: int = 5) -> MeasuredData:
    """A stand whose drive reaches the actuator ``delay_periods`` later (the command records
    samples of the continuous drive; the actuator sees that drive exactly, delayed)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 40.0, 1.0 / rate)

    def drive(at: np.ndarray) -> np.ndarray:
        return 150.0 + 90.0 * np.sin(2 * np.pi * 7.0 * at) + 30.0 * np.sin(2 * np.pi * 19.0 * at)

    V = drive(t)
    T = 46.0 - 3.0 * np.cos(2 * np.pi * t / 40.0)
    applied = drive(np.maximum(t - delay_periods / rate, 0.0))
    z = law(applied, T) + NOISE * rng.standard_normal(t.size)
    grid = lambda x: x[:, None, None]  # noqa: E731
    return MeasuredData(t, grid(V), t.copy(), grid(z), t[::25], grid(T[::25]))


@pytest.mark.slow
@pytest.mark.parametrize(("periods", "rate"), [(1.2, 500.0), (3.45, 250.0)])
def test_fractional_delay_is_resolved_to_a_twentieth_of_a_period(
    periods: float, rate: float
) -> None:
    cal = calibrate(fractional_stand(periods, rate), ("delay", "hysteresis", "sensor_lag"))
    assert [e.name for e in cal.effects] == ["delay"], cal.rounds
    found = cal.effects[0].parameters["delay_s"] * rate
    assert abs(found - periods) <= 0.05, found
    assert cal.final.heldout_rms <= 1.2 * NOISE


def pi_stand(
    weights: tuple[float, ...], thresholds: tuple[float, ...], seed: int = 8
) -> MeasuredData:
    """A stand whose drive passes a Prandtl-Ishlinskii operator with constant weights."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 1.0 / RATE)
    V = 160.0 + 80.0 * np.sin(2 * np.pi * 0.7 * t) + 40.0 * np.sin(2 * np.pi * 1.9 * t + 0.5)
    T = 46.0 - 3.0 * np.cos(2 * np.pi * t / 60.0)
    states = np.zeros(len(weights))
    r = np.asarray(thresholds)
    v_eff = np.empty_like(V)
    for i, v in enumerate(V):
        states = np.clip(states, v - r, v + r)
        v_eff[i] = (1.0 - sum(weights)) * v + float(np.dot(weights, states))
    z = law(v_eff, T) + NOISE * rng.standard_normal(t.size)
    grid = lambda x: x[:, None, None]  # noqa: E731
    return MeasuredData(t, grid(V), t + 0.001, grid(z), t[::10], grid(T[::10]))


@pytest.mark.slow
def test_drive_side_hysteresis_with_constant_weight_alone() -> None:
    cal = calibrate(pi_stand((0.2,), (25.0,)))
    assert [e.name for e in cal.effects] == ["hysteresis"], cal.rounds
    p = cal.effects[0].parameters
    assert p["weight"] == pytest.approx(0.2, rel=0.1)
    assert p["threshold_v"] == pytest.approx(25.0, rel=0.15)
    assert abs(p["decay_per_degc"]) < 0.05  # the weight does not follow the temperature
    assert cal.final.heldout_rms <= 1.2 * NOISE


@pytest.mark.slow
def test_three_operator_hysteresis_is_recovered_with_non_negative_weights() -> None:
    cal = calibrate(pi_stand((0.1, 0.15, 0.1), (4.0, 20.0, 60.0)))
    assert [e.name for e in cal.effects] == ["hysteresis"], cal.rounds
    p = cal.effects[0].parameters
    thresholds = [p["threshold_v"], p["threshold_v_2"], p["threshold_v_3"]]
    weights = [p["weight"], p["weight_2"], p["weight_3"]]
    assert "weight_4" not in p, p
    order = np.argsort(thresholds)
    np.testing.assert_allclose(np.array(thresholds)[order], [4.0, 20.0, 60.0], rtol=0.1)
    np.testing.assert_allclose(np.array(weights)[order], [0.1, 0.15, 0.1], rtol=0.15)
    assert cal.final.heldout_rms <= 1.2 * NOISE, (cal.final.heldout_rms, p)


def delayed_pi_stand(delay_periods: float, weight: float, threshold: float) -> MeasuredData:
    """500 Hz: the command reaches the actuator later (interpolated), then a play operator."""
    rng = np.random.default_rng(1)
    rate = 500.0
    t = np.arange(0.0, 60.0, 1.0 / rate)
    V = 160.0 + 80.0 * np.sin(2 * np.pi * 0.7 * t) + 40.0 * np.sin(2 * np.pi * 1.9 * t + 0.5)
    V = V + 15.0 * np.sin(2 * np.pi * 7.3 * t)
    T = 46.0 - 3.0 * np.cos(2 * np.pi * t / 60.0)
    applied = np.interp(t - delay_periods / rate, t, V, left=V[0])
    state, v_eff = 0.0, np.empty_like(V)
    for i, v in enumerate(applied):
        state = min(max(state, v - threshold), v + threshold)
        v_eff[i] = (1.0 - weight) * v + weight * state
    z = law(v_eff, T) + NOISE * rng.standard_normal(t.size)
    grid = lambda x: x[:, None, None]  # noqa: E731
    return MeasuredData(t, grid(V), t + 1e-4, grid(z), t[::50], grid(T[::50]))


@pytest.mark.slow
def test_fractional_delay_and_hysteresis_together() -> None:
    cal = calibrate(delayed_pi_stand(1.2, 0.2, 25.0), ("delay", "hysteresis", "sensor_lag"))
    assert sorted(e.name for e in cal.effects) == ["delay", "hysteresis"], cal.rounds
    found = {e.name: e.parameters for e in cal.effects}
    assert abs(found["delay"]["delay_s"] * 500.0 - 1.2) <= 0.1
    assert cal.final.heldout_rms <= 1.2 * NOISE
