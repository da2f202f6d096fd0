"""Temperature sensors: placement, lag, offset, noise and quantisation."""

from __future__ import annotations

import numpy as np
import pytest

from es_sim_plant.sensors import SensorArray, SensorConfig, flat_positions


def make(
    config: SensorConfig, shape: tuple[int, int] = (3, 3), lag: float | None = None, dt=0.01
) -> SensorArray:
    return SensorArray(
        shape,
        config=config,
        lag_tau=lag,
        dt=dt,
        initial_temperature=40.0,
        rng_offsets=np.random.default_rng(1),
        rng_noise=np.random.default_rng(2),
    )


def test_first_order_lag_step_response() -> None:
    tau, dt = 2.0, 0.01
    sensors = make(SensorConfig(noise_sd=0.0, resolution=0.0), lag=tau, dt=dt)
    hot = np.full((3, 3), 50.0)
    readings = []
    for _ in range(600):
        sensors.track(hot)
        readings.append(sensors.read()[0])
    t = dt * np.arange(1, 601)
    np.testing.assert_allclose(readings, 50.0 - 10.0 * np.exp(-t / tau), atol=1e-9)


def test_noise_statistics_offsets_and_quantisation() -> None:
    config = SensorConfig(noise_sd=0.05, resolution=0.01, offsets=tuple(np.linspace(-0.2, 0.2, 9)))
    sensors = make(config)
    sensors.track(np.full((3, 3), 45.0))
    samples = np.array([sensors.read() for _ in range(4000)])
    np.testing.assert_allclose(samples.mean(axis=0), 45.0 + np.linspace(-0.2, 0.2, 9), atol=0.005)
    np.testing.assert_allclose(samples.std(axis=0), 0.05, rtol=0.08)
    np.testing.assert_allclose(samples / 0.01, np.round(samples / 0.01), atol=1e-6)


def test_offset_spread_is_seeded() -> None:
    a = make(SensorConfig(offset_sd=0.1)).offsets
    b = make(SensorConfig(offset_sd=0.1)).offsets
    np.testing.assert_array_equal(a, b)
    assert 0.02 < a.std() < 0.3


def test_fractional_positions_interpolate_bilinearly() -> None:
    config = SensorConfig(positions=((0.0, 0.0), (0.5, 0.5), (2.0, 1.25)), noise_sd=0, resolution=0)
    sensors = make(config)
    grid = np.arange(9.0).reshape(3, 3)
    np.testing.assert_allclose(sensors.site_temperature(grid), [0.0, 2.0, 7.25])
    assert sensors.count == 3


def test_positions_off_grid_or_malformed_are_rejected() -> None:
    with pytest.raises(ValueError, match="within"):
        make(SensorConfig(positions=((3.5, 0.0),)))
    with pytest.raises(ValueError, match="positions"):
        SensorConfig.from_dict({"positions": [[1.0]]})
    with pytest.raises(ValueError, match="even"):
        flat_positions([1.0, 2.0, 3.0])
    assert flat_positions([1.0, 2.0, 0.5, 0.25]) == ((1.0, 2.0), (0.5, 0.25))
