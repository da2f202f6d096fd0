"""Each effect beyond the basic model shows its signature; all are off by default."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import Feedforward, FeedforwardConfig
from es_physics.effects.coupling import grid_laplacian
from es_physics.effects.drift import drift_factor
from es_physics.laws import hyperbolic_forward
from es_sim_plant.effects import EFFECT_NAMES, Effects
from es_sim_plant.plant import Plant, simulate
from es_sim_plant.scenario import Scenario


def bench(effects: dict[str, Any] | None = None, **extra: Any) -> Scenario:
    """A quiet test stand: 1 x 1 (or given) grid, 45 degC, fast thermal, no noise or spread."""
    data: dict[str, Any] = {
        "name": "bench",
        "grid": {"rows": 1, "cols": 1},
        "control_rate": 100.0,
        "sensor_rate": 10.0,
        "duration": 2.0,
        "base_temperature": {"points": [[0.0, 45.0]]},
        "thermal": {"face_capacitance": 0.001, "actuator_capacitance": 0.002},
        "sensors": {"noise_sd": 0.0, "resolution": 0.0},
        "actuators": {"spread": {}},
        "effects": effects or {},
    }
    data.update(extra)
    return Scenario.from_dict(data)


def run(scenario: Scenario, volts: np.ndarray, substeps: bool = False):
    plant = Plant(scenario)
    return plant, simulate(plant, commands=volts, steps=len(volts), record_substeps=substeps)


def test_all_effects_off_by_default() -> None:
    assert Effects().enabled_names() == []
    assert bench().effects.enabled_names() == []
    with pytest.raises(ValueError, match="unknown effect"):
        Effects.from_dict({"magic": True})
    with pytest.raises(ValueError, match="weight"):
        Effects.from_dict({"hysteresis": {"enabled": True, "weight": 2.0}})
    on = Effects().with_switches(dict.fromkeys(EFFECT_NAMES, True))
    assert on.enabled_names() == list(EFFECT_NAMES)


def test_basic_model_is_the_hyperbolic_law() -> None:
    volts = np.linspace(0.0, 300.0, 200)
    plant, res = run(bench(), volts)
    expected = hyperbolic_forward(volts[:, None, None], 45.0, plant.true_params)
    np.testing.assert_allclose(res.displacement, expected, rtol=1e-12)


def loop_area(v: np.ndarray, z: np.ndarray) -> float:
    """Signed area of the z(V) loop (shoelace)."""
    return float(0.5 * abs(np.sum(v * np.roll(z, -1) - np.roll(v, -1) * z)))


def test_hysteresis_loop_area_grows_towards_tm() -> None:
    t = np.arange(400) / 100.0
    volts = 150.0 + 100.0 * np.sin(2 * np.pi * t)  # four periods
    period = slice(300, 400)
    areas = {}
    for label, temp, on in (("off", 45.0, False), ("hot", 50.0, True), ("near_tm", 41.0, True)):
        scenario = bench(
            {"hysteresis": {"enabled": on, "weight": 0.2, "threshold_v": 30.0}},
            base_temperature={"points": [[0.0, temp]]},
        )
        _, res = run(scenario, volts)
        areas[label] = loop_area(volts[period], res.displacement[period, 0, 0])
    assert areas["off"] < 1e-20
    assert areas["hot"] > 0.0
    assert areas["near_tm"] > 2.0 * areas["hot"]


def test_prandtl_ishlinskii_operators_add_up() -> None:
    t = np.arange(300) / 100.0
    volts = 150.0 + 100.0 * np.sin(2 * np.pi * t)
    one = {"enabled": True, "weight": 0.2, "threshold_v": 30.0}
    _, single = run(bench({"hysteresis": one}), volts)
    _, unused = run(bench({"hysteresis": {**one, "threshold_v_2": 10.0}}), volts)
    _, two = run(bench({"hysteresis": {**one, "weight_2": 0.1, "threshold_v_2": 10.0}}), volts)
    np.testing.assert_array_equal(unused.displacement, single.displacement)  # weight_2 = 0
    period = slice(200, 300)
    area = lambda r: loop_area(volts[period], r.displacement[period, 0, 0])  # noqa: E731
    assert area(two) > 1.2 * area(single)


def test_delay_found_by_cross_correlation() -> None:
    rng = np.random.default_rng(5)
    volts = rng.uniform(50.0, 250.0, 300)
    scenario = bench({"delay": {"enabled": True, "delay_s": 0.023}})
    _, res = run(scenario, volts, substeps=True)
    _, ref = run(bench(), volts, substeps=True)
    z = res.substep_displacement[:, 0, 0] - res.substep_displacement[:, 0, 0].mean()
    z0 = ref.substep_displacement[:, 0, 0] - ref.substep_displacement[:, 0, 0].mean()
    lags = np.arange(0, 60)
    corr = [np.dot(z[lag:], z0[: z0.size - lag]) for lag in lags]
    internal_dt = 0.01 / scenario.actuators.substeps
    assert lags[int(np.argmax(corr))] * internal_dt == pytest.approx(0.023, abs=internal_dt)


def test_coupling_spreads_to_neighbours() -> None:
    volts = np.zeros((5, 3, 3))
    volts[:, 1, 1] = 200.0
    scenario = bench(
        {"coupling": {"enabled": True, "coefficient": 0.05}}, grid={"rows": 3, "cols": 3}
    )
    plant, res = run(scenario, volts)
    z = res.displacement[-1]
    free = float(hyperbolic_forward(200.0, 45.0, plant.true_params.select((1, 1))))
    assert z[1, 1] == pytest.approx(free * (1 - 4 * 0.05), rel=1e-9)
    assert z[0, 1] == pytest.approx(free * 0.05, rel=1e-9)
    assert z[0, 0] == 0.0
    np.testing.assert_allclose(grid_laplacian(np.ones((3, 4))), 0.0)


def test_thermal_expansion_follows_temperature_without_voltage() -> None:
    scenario = bench(
        {"thermal_expansion": {"enabled": True, "alpha_m_per_degc": 0.5e-9}},
        base_temperature={"points": [[0.0, 45.0], [1.0, 47.0]]},
        duration=40.0,
    )
    plant, res = run(scenario, np.zeros(4000))
    T_end = plant.actuator_temperature()[0, 0]
    assert res.displacement[-1, 0, 0] == pytest.approx(0.5e-9 * (T_end - 45.0), rel=1e-9)
    assert res.displacement[-1, 0, 0] > 0.5e-9


def test_drift_scales_the_gain_over_time() -> None:
    drift = {"enabled": True, "fraction": 0.05, "tau_s": 1.0, "nu": 0.7}
    scenario = bench({"drift": drift})
    volts = np.full(200, 150.0)
    _, res = run(scenario, volts)
    _, ref = run(bench(), volts)
    ratio = res.displacement[:, 0, 0] / ref.displacement[:, 0, 0]
    t_end = res.time + 0.01
    expected = drift_factor(t_end, 0.05, 1.0, 0.7)
    np.testing.assert_allclose(ratio, expected, rtol=1e-12)
    assert ratio[-1] < 0.97


def test_temperature_curvature_adds_quadratic_terms() -> None:
    curvature = {"enabled": True, "m3": 2.0e-18, "k3": 0.0}
    plant, res = run(bench({"temperature_curvature": curvature}), np.full(10, 150.0))
    _, ref = run(bench(), np.full(10, 150.0))
    assert plant.true_params.m3 == pytest.approx(2.0e-18)
    t_star = 45.0 - 38.0
    m_lin = 1504e-18 - 41.5e-18 * t_star
    expected = (m_lin + 2.0e-18 * t_star**2) / m_lin
    assert res.displacement[-1, 0, 0] / ref.displacement[-1, 0, 0] == pytest.approx(expected)


def test_self_heating_warms_a_fast_driven_actuator() -> None:
    t = np.arange(2000) / 1000.0
    volts = 300.0 * np.sin(2 * np.pi * 200.0 * t)
    heating = {"enabled": True, "loss_w_per_hz_v2": 4.7e-9}
    kwargs: dict[str, Any] = {"control_rate": 1000.0, "duration": 2.0}
    plant_on, on = run(bench({"self_heating": heating}, **kwargs), volts)
    _, off = run(bench(**kwargs), volts)
    assert off.actuator_temperature.max() == pytest.approx(45.0)
    ac_rise = plant_on.actuator_temperature()[0, 0] - 45.0
    assert ac_rise > 0.05
    # DC drive: only the one charging swing at the start dissipates.
    plant_dc, _ = run(bench({"self_heating": heating}, **kwargs), np.full(2000, 300.0))
    assert plant_dc.actuator_temperature()[0, 0] - 45.0 < 0.1 * ac_rise
    assert on.actuator_temperature[-1, 0, 0] > on.actuator_temperature[100, 0, 0]


def test_sensor_lag_delays_the_reading() -> None:
    lag = {"enabled": True, "tau_s": 1.0}
    ramp = {"points": [[0.0, 41.0], [3.0, 47.0]]}
    _, res = run(bench({"sensor_lag": lag}, base_temperature=ramp, duration=3.0), np.zeros(300))
    _, ref = run(bench(base_temperature=ramp, duration=3.0), np.zeros(300))
    assert np.all(res.temperature_raw[10:] < ref.temperature_raw[10:] - 0.5)
    truth = ref.actuator_temperature[ref.sensor_step, 0, 0]
    np.testing.assert_allclose(ref.temperature_raw[:, 0], truth, atol=1e-9)


def test_frequency_dispersion_lowers_the_gain_of_fast_drive_only() -> None:
    """V_eff = V - r highpass_fc(V): DC passes, far above f_c the gain is 1 - r."""
    r, fc = 0.3, 2.0
    on = {"frequency_dispersion": {"enabled": True, "fraction": r, "corner_hz": fc}}
    plant, dc = run(bench(on), np.full(200, 200.0))  # 2 s of DC: settled after ~12 tau
    np.testing.assert_allclose(
        dc.displacement[-1], hyperbolic_forward(200.0, 45.0, plant.true_params), rtol=1e-9
    )
    # a 50 Hz square wave (25 x f_c) around 150 V: the swing of V_eff shrinks to 1 - r
    volts = np.where(np.arange(200) % 2 == 0, 170.0, 130.0)
    _, fast = run(bench(on), volts)
    _, ref = run(bench(), volts)
    z, z_ref = fast.displacement[-20:, 0, 0], ref.displacement[-20:, 0, 0]
    ratio = np.ptp(z) / np.ptp(z_ref)
    assert 0.68 < ratio < 0.74  # about 1 - r, plus the little relaxation within a step


def test_feedforward_undoes_the_plants_frequency_dispersion() -> None:
    """The feedforward's inverse (command rate) against the plant's filter (internal rate)."""
    r, fc = 0.3, 5.0
    scenario = bench({"frequency_dispersion": {"enabled": True, "fraction": r, "corner_hz": fc}})
    params = Plant(scenario).true_params
    z_ref = (60 + 30 * np.sin(2 * np.pi * 10.0 * np.arange(200) / 100.0)) * 1e-9
    rms = []
    for comp in ({}, {"dispersion_fraction": r, "dispersion_corner_hz": fc}):
        config = FeedforwardConfig(
            shape=(1, 1), params=params, compensation=CompensationParams(**comp)
        )
        ff = Feedforward(config)
        ff.update_temperature(np.full((1, 1), 45.0), 0.0)
        volts = [ff.command(np.full((1, 1), z), k * 0.01).voltage for k, z in enumerate(z_ref)]
        _, res = run(scenario, np.array(volts))
        rms.append(float(np.sqrt(np.mean((res.displacement[100:, 0, 0] - z_ref[100:]) ** 2))))
    uncompensated, compensated = rms
    assert uncompensated > 2e-9  # 10 Hz is well above f_c: the gain is down by about r
    assert compensated < 0.1 * uncompensated
