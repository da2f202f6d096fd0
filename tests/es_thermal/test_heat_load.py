"""Hostile heat loads: rejected at the estimator, and the model's fit survives them (no ROS)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from es_thermal.estimator import EstimatorConfig, TemperatureEstimator
from es_thermal.faults import FaultConfig, heat_load_problem
from es_thermal.interpolation import actuator_positions
from es_thermal.kalman import KalmanTuning, ModelEstimator
from es_thermal.network import NetworkParams

SHAPE = (3, 3)
HOSTILE = [1e6, 1e12, 1e300, -1e6, 10.5, -1e-3]  # the last two: just past the default limits


def _noisy(rng: np.random.Generator, value: float = 45.0) -> np.ndarray:
    return value + 0.01 * rng.standard_normal(SHAPE[0] * SHAPE[1])


def test_heat_load_problem_passes_credible_loads() -> None:
    cfg = FaultConfig()
    exposure = np.full(SHAPE, 2.0 / 9)  # 2 W on the whole mirror
    assert heat_load_problem(exposure, cfg) is None
    assert heat_load_problem(np.zeros(SHAPE), cfg) is None
    assert heat_load_problem(np.full(SHAPE, -1e-9), cfg) is None  # rounding of a power map
    assert heat_load_problem(np.full(SHAPE, cfg.max_heat_load), cfg) is None


@pytest.mark.parametrize(
    ("value", "reason"),
    [
        (np.nan, "NaN or inf in 1 cell"),
        (-np.inf, "NaN or inf"),
        (-1e-3, "negative"),
        (-1e6, "negative"),
        (10.5, "above max_heat_load 10 W"),
        (1e300, "above max_heat_load"),
    ],
)
def test_heat_load_problem_names_the_fault(value: float, reason: str) -> None:
    heat = np.zeros(SHAPE)
    heat[1, 2] = value
    problem = heat_load_problem(heat, FaultConfig())
    assert problem is not None and reason in problem


def test_heat_load_limits_are_parameters() -> None:
    cfg = FaultConfig(max_heat_load=100.0, heat_load_tolerance=0.01)
    assert heat_load_problem(np.full(SHAPE, 50.0), cfg) is None
    assert heat_load_problem(np.full(SHAPE, -0.005), cfg) is None
    assert heat_load_problem(np.full(SHAPE, -0.02), cfg) is not None
    for bad in ({"max_heat_load": 0.0}, {"max_heat_load": np.inf}, {"heat_load_tolerance": -1.0}):
        with pytest.raises(ValueError, match="heat_load"):
            FaultConfig(**bad)


@pytest.fixture(scope="module")
def model_estimator() -> TemperatureEstimator:
    """Built once (construction solves a Riccati); tests use deep copies."""
    cfg = EstimatorConfig(*SHAPE, actuator_positions(*SHAPE), kind="model")
    return TemperatureEstimator(cfg)


@pytest.mark.parametrize("load", HOSTILE)
def test_rejected_heat_load_leaves_the_estimate_as_if_never_sent(
    model_estimator: TemperatureEstimator, load: float
) -> None:
    """The last accepted load is held: a twin that never saw the bad load agrees exactly."""
    est, twin = copy.deepcopy(model_estimator), copy.deepcopy(model_estimator)
    rng = np.random.default_rng(3)
    held = np.full(SHAPE, 0.05)
    t = 0.0
    final: np.ndarray | None = None
    for step in range(40):
        t += 0.1
        readings = _noisy(rng)
        if step == 2:
            est.set_heat_load(held)
            twin.set_heat_load(held)
        if 3 <= step < 8:
            with pytest.raises(ValueError, match="heat load"):
                est.set_heat_load(np.full(SHAPE, load))
        out, expected = est.update(t, readings), twin.update(t, readings)
        assert out.temperatures is not None and expected.temperatures is not None
        np.testing.assert_array_equal(out.temperatures, expected.temperatures)
        final = out.temperatures
    assert est.model is not None and twin.model is not None
    assert est.model.biases == twin.model.biases
    assert final is not None and np.all(np.abs(final - 45.0) < 1.0)


def test_restart_rebuilds_the_estimate_from_the_next_readings(
    model_estimator: TemperatureEstimator,
) -> None:
    est = copy.deepcopy(model_estimator)
    rng = np.random.default_rng(4)
    for k in range(10):
        est.update(0.1 * (k + 1), _noisy(rng, 40.0))
    est.restart()
    out = est.update(1.1, np.full(9, 45.0))  # one period on: without the restart, near 40
    assert out.temperatures is not None
    np.testing.assert_allclose(out.temperatures, 45.0)
    assert est.model is not None and est.model.biases == {"heat_gain": 0.0, "time_scale": 0.0}


def _bare_model() -> ModelEstimator:
    return ModelEstimator(
        *SHAPE,
        actuator_positions(*SHAPE),
        params=NetworkParams().time_scaled(0.05),
        sensor_tau=0.0,
        sample_period=0.1,
        tuning=KalmanTuning(),
    )


@pytest.mark.parametrize("load", [1e6, 1e12, 1e300, -1e300])
def test_model_error_fit_stays_finite_under_an_extreme_load(load: float) -> None:
    """Given to the model directly (no facade check), an absurd load wrecks the state, but the
    model-error fit stays finite, within its limits, and raises nothing."""
    model = _bare_model()
    rng = np.random.default_rng(5)
    cells = SHAPE[0] * SHAPE[1]
    valid = np.ones(cells, bool)
    model.initialise(np.full(cells, 45.0), np.full(cells, 45.0), valid)
    limit = model.tuning.bias_limit
    with np.errstate(over="ignore", invalid="ignore"):  # the wrecked state may overflow
        for step in range(20):
            model.predict(np.full(cells, load if step < 3 else 0.0))
            model.correct(_noisy(rng), valid)
            biases = np.array(list(model.biases.values()))
            assert np.all(np.isfinite(biases)) and np.all(np.abs(biases) <= limit)
            assert np.all(np.isfinite(model._info)) and np.all(np.isfinite(model._info_vector))


def test_model_refuses_a_non_finite_load_without_changing_state() -> None:
    model = _bare_model()
    cells = SHAPE[0] * SHAPE[1]
    model.initialise(np.full(cells, 45.0), np.full(cells, 45.0), np.ones(cells, bool))
    before = model.actuator_temperatures()
    heat = np.zeros(cells)
    heat[4] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        model.predict(heat)
    np.testing.assert_array_equal(model.actuator_temperatures(), before)
