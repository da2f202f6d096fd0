"""The simulated resonance sweeps: law, noise and resolution, round robin, failures, seeds."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from es_sim_plant.plant import Plant, simulate
from es_sim_plant.resonance import ResonanceConfig, ResonanceSensor
from es_sim_plant.scenario import Scenario, load_scenario

SHAPE = (6, 8)


def sensor(**changes: object) -> ResonanceSensor:
    config = replace(ResonanceConfig(enabled=True), **changes)  # type: ignore[arg-type]
    return ResonanceSensor(
        SHAPE, config, np.random.default_rng(1), np.random.default_rng(2)
    )


def sweep_all(s: ResonanceSensor, temperature: np.ndarray, voltage: np.ndarray) -> np.ndarray:
    """Return one full round of readings (every actuator once), (R, C)."""
    out = np.full(SHAPE, np.nan)
    for _ in range(s.groups):
        reading = s.measure(temperature, voltage)
        out = np.where(np.isfinite(reading), reading, out)
    return out


def test_readings_follow_the_law_with_the_documented_noise_and_resolution() -> None:
    s = sensor(f0_spread_hz=0.0, a_t_spread=0.0, a_v_spread=0.0, group_size=SHAPE[0] * SHAPE[1])
    temperature = np.full(SHAPE, 45.0)
    voltage = np.full(SHAPE, -120.0)
    readings = np.array([s.measure(temperature, voltage) for _ in range(400)])
    cfg = s.config
    truth = cfg.f0_hz + cfg.a_t_hz_per_degc * 5.0 + cfg.a_v_hz_per_v * 120.0
    step = cfg.frequency_step_hz
    assert np.all(np.abs(readings / step - np.round(readings / step)) < 1e-9)  # resolution
    assert abs(readings.mean() - truth) < 0.5  # unbiased (19200 readings)
    expected_sd = np.sqrt(cfg.noise_hz**2 + step**2 / 12)
    assert readings.std() == pytest.approx(expected_sd, rel=0.05)
    # the sweep model: noise falls with the square root of the sweep time
    slower = replace(cfg, dwell_s=4 * cfg.dwell_s)
    assert slower.noise_hz == pytest.approx(cfg.noise_hz / 2)


def test_spread_is_seeded_and_has_the_configured_size() -> None:
    a, b = sensor(), sensor()
    np.testing.assert_array_equal(a.f0, b.f0)
    big = ResonanceSensor(
        (40, 40), ResonanceConfig(enabled=True), np.random.default_rng(3), np.random.default_rng(4)
    )
    assert np.std(big.f0) == pytest.approx(big.config.f0_spread_hz, rel=0.1)
    assert np.std(big.a_t / big.config.a_t_hz_per_degc) == pytest.approx(0.03, rel=0.1)


def test_round_robin_measures_each_actuator_once_per_round_spread_over_the_grid() -> None:
    s = sensor(group_size=16)  # 48 actuators -> 3 groups
    assert s.groups == 3
    temperature, voltage = np.full(SHAPE, 40.0), np.zeros(SHAPE)
    seen = np.zeros(SHAPE, int)
    for cycle in range(6):
        reading = s.measure(temperature, voltage)
        swept = np.isfinite(reading)
        assert swept.sum() == 16
        assert np.unique(np.nonzero(swept)[0]).size == SHAPE[0]  # every row has some
        seen += swept
        if cycle == 2:
            assert np.all(seen == 1)
    assert np.all(seen == 2)


@pytest.mark.parametrize("failure", ["nan", "stuck", "implausible"])
def test_failed_channels(failure: str) -> None:
    s = sensor(failed_channels=(5,), failure=failure)
    voltage = np.zeros(SHAPE)
    first = sweep_all(s, np.full(SHAPE, 40.0), voltage)
    later = sweep_all(s, np.full(SHAPE, 43.0), voltage)
    healthy = np.ones(SHAPE, bool)
    healthy.flat[5] = False
    assert np.all(np.isfinite(later[healthy]))
    assert np.all(np.abs(later - first)[healthy] > 2.5 * 3227.0)
    if failure == "nan":
        assert np.isnan(first.flat[5]) and np.isnan(later.flat[5])
    elif failure == "stuck":
        assert later.flat[5] == first.flat[5]
    else:
        truth = s.true_frequency(np.full(SHAPE, 43.0), voltage).flat[5]
        assert later.flat[5] - truth == pytest.approx(s.config.implausible_offset_hz, abs=200.0)


def exposure(duration: float = 2.0) -> Scenario:
    return load_scenario("dm_exposure").with_overrides(rows=4, cols=4, duration=duration)


def test_off_by_default_and_switching_on_changes_no_other_draw() -> None:
    sc = exposure()
    assert not sc.resonance.enabled
    plain = simulate(Plant(sc), commands=np.full(Plant(sc).steps, 80.0))
    assert plain.resonance is None
    on = replace(sc, resonance=ResonanceConfig(enabled=True, group_size=8))
    sensed = simulate(Plant(on), commands=np.full(Plant(on).steps, 80.0))
    np.testing.assert_array_equal(plain.temperature_raw, sensed.temperature_raw)
    np.testing.assert_array_equal(plain.displacement, sensed.displacement)
    assert sensed.resonance is not None
    assert sensed.resonance.shape == (plain.sensor_step.size, 4, 4)
    assert np.isfinite(sensed.resonance).sum() == 8 * plain.sensor_step.size


def test_scenario_key_is_validated() -> None:
    assert ResonanceConfig.from_dict({"enabled": True, "group_size": 4}).group_size == 4
    with pytest.raises(ValueError, match="unknown key"):
        ResonanceConfig.from_dict({"bogus": 1})
    with pytest.raises(ValueError, match="group_size"):
        ResonanceConfig.from_dict({"group_size": 0})
    with pytest.raises(ValueError, match="failure"):
        ResonanceConfig.from_dict({"failure": "melted"})
    with pytest.raises(ValueError, match="failed_channels"):
        ResonanceSensor(
            SHAPE, ResonanceConfig(failed_channels=(99,)),
            np.random.default_rng(0), np.random.default_rng(0),
        )  # fmt: skip
