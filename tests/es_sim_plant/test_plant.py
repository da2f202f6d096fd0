"""Plant core: scenarios, determinism, offline runner, command checks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from es_physics.laws import hyperbolic_inverse
from es_sim_plant.plant import Observation, Plant, simulate
from es_sim_plant.scenario import available_scenarios, load_scenario

SHIPPED = ("thesis_ac", "thesis_dc_ac", "dm_exposure", "characterisation")


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenarios_load(name: str) -> None:
    assert name in available_scenarios()
    scenario = load_scenario(name)
    plant = Plant(scenario)
    assert plant.steps == round(scenario.duration * scenario.control_rate)
    # the default simulator's sensor lag at most; every other effect is a calibration topic
    assert set(scenario.effects.enabled_names()) <= {"sensor_lag"}


def test_thesis_scenarios_keep_the_thesis_ranges() -> None:
    ac = load_scenario("thesis_ac")
    levels = sorted(set(ac.base.temperatures))
    assert levels[0] == 40.0 and levels[-1] == 52.0
    assert ac.base.interpolation == "step"
    set_points = [ac.setpoint.offset + s * ac.setpoint.sine_amplitude for s in (-1, 1)]
    assert set_points == pytest.approx([0.0, 100e-9])
    dc = load_scenario("thesis_dc_ac")
    assert (dc.base.temperatures[0], dc.base.temperatures[-1]) == (41.0, 51.0)
    assert (dc.setpoint.offset, dc.setpoint.sine_amplitude) == pytest.approx((100e-9, 25e-9))
    dm = load_scenario("dm_exposure")
    assert dm.rows >= 12 and dm.cols >= 12
    assert dm.illumination is not None and dm.illumination.pattern != "uniform"


def test_time_scale_stretches_slow_times_only() -> None:
    short = load_scenario("thesis_ac")
    long = load_scenario("thesis_ac", time_scale=1.0)
    assert long.duration == pytest.approx(short.duration / short.time_scale)
    assert long.base.times[-1] == pytest.approx(short.base.times[-1] / short.time_scale)
    assert long.setpoint.sine_frequency == short.setpoint.sine_frequency
    assert long.thermal.actuator_capacitance == pytest.approx(
        short.thermal.actuator_capacitance / short.time_scale
    )


def test_bad_scenarios_give_one_readable_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown scenario 'nope'"):
        load_scenario("nope")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ngrid: {rows: 2, cols: 2}\nwarp_drive: 1\n")
    with pytest.raises(ValueError, match="warp_drive"):
        load_scenario(str(bad))
    bad.write_text("name: x\nsetpoint: {offset: 1.0e-9, sine: {amplitude: 5.0e-9}}\n")
    with pytest.raises(ValueError, match="below 0"):
        Plant(load_scenario(str(bad)))
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ValueError, match="cannot read scenario"):
        load_scenario(str(bad))
    with pytest.raises(ValueError, match="does not exist"):
        load_scenario(str(tmp_path / "missing.yaml"))


def small_exposure(seed: int | None = None, **effects: bool):
    scenario = load_scenario("dm_exposure").with_overrides(
        rows=4, cols=5, duration=1.0, seed=seed, effects=effects or None
    )
    return scenario


def perfect_controller(plant: Plant):
    def control(obs: Observation) -> np.ndarray:
        return hyperbolic_inverse(
            obs.setpoint, plant.actuator_temperature(), plant.true_params
        ).voltage

    return control


def test_same_seed_same_trajectories_different_seed_differs() -> None:
    runs = []
    for seed in (7, 7, 8):
        plant = Plant(small_exposure(seed, hysteresis=True, drift=True))
        runs.append(simulate(plant, perfect_controller(plant)))
    a, b, c = runs
    for field in ("displacement", "temperature_raw", "actuator_temperature", "command"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(a.temperature_raw, c.temperature_raw)
    assert not np.array_equal(a.true_params.m2, c.true_params.m2)


def test_switching_an_effect_keeps_the_other_random_draws() -> None:
    plain = Plant(small_exposure(3))
    with_delay = Plant(small_exposure(3, delay=True))
    np.testing.assert_array_equal(plain.true_params.m2, with_delay.true_params.m2)
    np.testing.assert_array_equal(plain.read_sensors(), with_delay.read_sensors())


def test_runner_series_shapes_and_perfect_inverse_tracks() -> None:
    plant = Plant(small_exposure(1))
    res = simulate(plant, perfect_controller(plant))
    K = plant.steps
    assert res.time.shape == (K,) and res.displacement.shape == (K, 4, 5)
    assert res.sensor_step.tolist() == list(range(0, K, plant.sensor_every))
    assert res.temperature_raw.shape == (len(res.sensor_step), 20)
    # With perfect knowledge of the true parameters and temperature, only the temperature
    # change within one step remains.
    assert np.max(np.abs(res.displacement - res.setpoint)) < 1e-10
    assert res.heat_load.sum(axis=(1, 2)).max() == pytest.approx(2.0)
    assert np.all(res.actuator_temperature[-1] > 42.0)


def test_observation_only_carries_sensor_data_when_due() -> None:
    plant = Plant(small_exposure(1))
    seen: list[Observation] = []

    def record(obs: Observation) -> np.ndarray:
        seen.append(obs)
        return np.zeros(plant.shape)

    simulate(plant, record, steps=25)
    due = [obs.step for obs in seen if obs.temperature_raw is not None]
    assert due == [0, 10, 20]
    assert all(obs.heat_load is None for obs in seen if obs.temperature_raw is None)


def test_check_command_reasons_and_amplifier_saturation() -> None:
    plant = Plant(small_exposure(1))
    good = np.full((4, 5), 100.0)
    assert plant.check_command(good) is None
    assert "shape" in str(plant.check_command(np.zeros((5, 4))))
    nan = good.copy()
    nan[1, 2] = np.nan
    assert "non-finite" in str(plant.check_command(nan))
    assert "limit" in str(plant.check_command(good * 4))
    with pytest.raises(ValueError, match="non-finite"):
        plant.step(nan)
    plant.step(good * 4)
    np.testing.assert_array_equal(plant.actuators.command, 350.0)


def test_characterisation_plays_its_excitation_with_noise() -> None:
    scenario = load_scenario("characterisation").with_overrides(rows=2, cols=3, duration=2.0)
    plant = Plant(scenario)
    res = simulate(plant, steps=200)
    assert np.abs(res.command).max() <= 350.0
    assert np.std(res.command[:, 0, 0]) > 10.0
    noise = res.displacement_measured - res.displacement
    assert 0.3e-9 < noise.std() < 0.7e-9
    with pytest.raises(ValueError, match="controller"):
        simulate(Plant(load_scenario("thesis_ac")), steps=3)
