"""Feedforward core: every mode against the model as plant, safety rules, reconfiguration."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from es_feedforward.compensation import CompensationParams
from es_feedforward.feedforward import (
    Feedforward,
    FeedforwardConfig,
    Mode,
    ObserverGains,
    linearization_error_bound,
)
from es_physics.laws import (
    CompiledLaws,
    Status,
    hyperbolic_forward,
    quadratic_forward,
    z_sat,
)
from es_physics.params import ActuatorParams

from .plantlike import grid_params

SHAPE = (3, 4)
PARAMS = grid_params(SHAPE)
# every actuator at its own temperature across the 40-52 degC band
TEMPERATURE = np.linspace(40.0, 52.0, 12).reshape(SHAPE)
NM = 1e-9


def setpoints(seed: int, high: float = 170 * NM) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.0, high, SHAPE)


def make(mode: Mode, **changes: object) -> Feedforward:
    config = FeedforwardConfig(shape=SHAPE, params=PARAMS, mode=mode, **changes)  # type: ignore[arg-type]
    ff = Feedforward(config)
    ff.update_temperature(TEMPERATURE, 0.0)
    return ff


@pytest.mark.parametrize(
    ("mode", "plant"),
    [(Mode.INVERSE_HYPERBOLIC, hyperbolic_forward), (Mode.INVERSE_QUADRATIC, quadratic_forward)],
)
def test_inverse_modes_track_their_model_to_0_01_nm(mode: Mode, plant: object) -> None:
    ff = make(mode)
    for step in range(5):
        z = setpoints(step, high=120 * NM)
        result = ff.command(z, 0.01 * step)
        assert not result.held
        assert np.all(result.status == Status.OK)
        z_plant = plant(result.voltage, TEMPERATURE, PARAMS)  # type: ignore[operator]
        assert np.max(np.abs(z_plant - z)) < 0.01 * NM


def test_observer_mode_converges_to_the_set_point() -> None:
    ff = make(Mode.OBSERVER)
    z = setpoints(7)
    for step in range(3):
        result = ff.command(z, 0.01 * step)
    z_plant = hyperbolic_forward(result.voltage, TEMPERATURE, PARAMS)
    assert np.max(np.abs(z_plant - z)) < 0.01 * NM
    assert result.model_error is not None
    np.testing.assert_allclose(result.model_error, z_plant - z, atol=1e-15)


def test_observer_mode_tracks_a_slow_sine() -> None:
    ff = make(Mode.OBSERVER)
    worst = 0.0
    for step in range(200):  # 1 Hz sine sampled at 1 kHz
        z = np.full(SHAPE, (80 + 40 * np.sin(2 * np.pi * step / 1000)) * NM)
        result = ff.command(z, step / 1000)
        if step >= 3:
            worst = max(
                worst, np.max(np.abs(hyperbolic_forward(result.voltage, TEMPERATURE, PARAMS) - z))
            )
    assert worst < 0.01 * NM


def test_linearized_mode_reports_its_own_error_within_the_bound() -> None:
    ff = make(Mode.LINEARIZED_DMAX)
    laws = CompiledLaws(PARAMS, SHAPE).at(TEMPERATURE)
    z_mid = laws.z_sat / 3
    for amplitude in (1 * NM, 10 * NM, 40 * NM):
        z = z_mid + amplitude * np.cos(np.arange(12).reshape(SHAPE))
        result = ff.command(z, 0.0)
        error = hyperbolic_forward(result.voltage, TEMPERATURE, PARAMS) - z
        assert result.model_error is not None
        np.testing.assert_allclose(result.model_error, error, atol=1e-18)
        bound = linearization_error_bound(laws, amplitude)
        assert np.all(np.abs(error) <= bound * (1 + 1e-9))
        # the bound is tight: reached at one of the ends of the span
        above = ff.command(z_mid + amplitude, 0.0).model_error
        below = ff.command(z_mid - amplitude, 0.0).model_error
        assert above is not None and below is not None
        np.testing.assert_allclose(np.maximum(np.abs(above), np.abs(below)), bound, rtol=1e-6)
    # small deviations around z_sat/3 are nearly exact (the slope is flat at its maximum)
    small = ff.command(z_mid + 0.5 * NM, 0.0)
    assert np.max(np.abs(small.model_error)) < 1e-3 * NM  # type: ignore[arg-type]


def test_uncompensated_mode_uses_the_reference_temperature_only() -> None:
    config = FeedforwardConfig(
        shape=SHAPE, params=PARAMS, mode=Mode.UNCOMPENSATED, reference_temperature=46.0
    )
    ff = Feedforward(config)
    z = setpoints(2, high=120 * NM)
    result = ff.command(z, 0.0)  # no temperature needed
    assert not result.held
    at_reference = hyperbolic_forward(result.voltage, 46.0, PARAMS)
    assert np.max(np.abs(at_reference - z)) < 0.01 * NM
    ff.update_temperature(TEMPERATURE, 0.0)
    assert np.array_equal(ff.command(z, 0.1).voltage, result.voltage)
    # against the plant at 40-52 degC the temperature effect shows (the baseline's error)
    off = hyperbolic_forward(result.voltage, TEMPERATURE, PARAMS) - z
    assert np.max(np.abs(off)) > 1 * NM


def test_setpoints_outside_the_domain_are_clipped_and_reported() -> None:
    ff = make(Mode.INVERSE_HYPERBOLIC)
    good = ff.command(setpoints(1, 100 * NM), 0.0)
    z = setpoints(1, 100 * NM)
    z[0, 0] = -5 * NM
    z[0, 1] = 2 * float(np.max(z_sat(TEMPERATURE, PARAMS)))
    z[0, 2] = np.nan
    z[0, 3] = np.inf
    result = ff.command(z, 0.01)
    assert result.status[0].tolist() == [
        Status.CLIPPED_LOW,
        Status.CLIPPED_HIGH,
        Status.INVALID,
        Status.INVALID,
    ]
    assert result.voltage[0, 0] == 0.0
    assert result.voltage[0, 1] == ff.config.v_limit
    # an invalid element holds its last voltage; the others are computed as usual
    assert result.voltage[0, 2] == good.voltage[0, 2]
    assert result.voltage[0, 3] == good.voltage[0, 3]
    np.testing.assert_array_equal(result.voltage[1:], good.voltage[1:])
    assert (good.worst, result.worst) == (Status.OK, Status.INVALID)


def test_a_held_command_reports_the_worst_status_of_the_command_it_repeats() -> None:
    config = FeedforwardConfig(shape=SHAPE, params=PARAMS, temperature_timeout=0.5)
    ff = Feedforward(config)
    assert ff.command(setpoints(1, 100 * NM), 0.0).worst == Status.OK  # 0 V, nothing clipped
    ff.update_temperature(TEMPERATURE, 1.0)
    z = setpoints(1, 100 * NM)
    z[1, 1] = 2 * float(np.max(z_sat(TEMPERATURE, PARAMS)))
    clipped = ff.command(z, 1.0)
    stale = ff.command(setpoints(2, 100 * NM), 1.6)
    assert not clipped.held and stale.held
    assert clipped.worst == stale.worst == Status.CLIPPED_HIGH


def test_missing_stale_and_invalid_temperature_hold_the_last_good_command() -> None:
    config = FeedforwardConfig(shape=SHAPE, params=PARAMS, temperature_timeout=0.5)
    ff = Feedforward(config)
    z = setpoints(3, 100 * NM)
    missing = ff.command(z, 0.0)
    assert missing.held and "no temperature" in (missing.problem or "")
    assert np.all(missing.voltage == 0.0)
    ff.update_temperature(TEMPERATURE, 1.0)
    good = ff.command(z, 1.2)
    assert not good.held
    stale = ff.command(setpoints(4, 100 * NM), 1.6)
    assert stale.held and "stale" in (stale.problem or "")
    np.testing.assert_array_equal(stale.voltage, good.voltage)
    bad = TEMPERATURE.copy()
    bad[1, 1] = np.nan
    assert ff.update_temperature(bad, 1.7) is not None
    invalid = ff.command(setpoints(5, 100 * NM), 1.7)
    assert invalid.held and "non-finite" in (invalid.problem or "")
    np.testing.assert_array_equal(invalid.voltage, good.voltage)
    bad[1, 1] = 900.0  # a broken sensor, not an actuator state
    assert "outside" in (ff.update_temperature(bad, 1.75) or "")
    assert ff.command(z, 1.75).held
    assert ff.update_temperature(TEMPERATURE, 1.8) is None
    assert not ff.command(z, 1.8).held


def test_wrong_shapes_are_rejected() -> None:
    ff = make(Mode.INVERSE_HYPERBOLIC)
    with pytest.raises(ValueError, match="set point grid"):
        ff.command(np.zeros((4, 3)), 0.0)
    with pytest.raises(ValueError, match="temperature grid"):
        ff.update_temperature(np.zeros(12), 0.0)


@settings(max_examples=60, deadline=None)
@given(
    z=arrays(np.float64, SHAPE, elements=st.floats(allow_nan=True, allow_infinity=True)),
    T=arrays(np.float64, SHAPE, elements=st.floats(-1e3, 1e3) | st.just(np.nan)),
    mode=st.sampled_from(list(Mode)),
)
def test_output_is_always_finite_and_within_the_limit(
    z: np.ndarray, T: np.ndarray, mode: Mode
) -> None:
    ff = Feedforward(FeedforwardConfig(shape=SHAPE, params=PARAMS, mode=mode, v_limit=200.0))
    ff.update_temperature(T, 0.0)
    for step in range(2):
        result = ff.command(z, 0.001 * step)
        assert np.all(np.isfinite(result.voltage))
        assert np.all((result.voltage >= 0.0) & (result.voltage <= 200.0))
        assert result.status.shape == SHAPE


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"v_limit": -1.0}, "v_limit"),
        ({"params": ActuatorParams(m2=np.ones((2, 2)))}, "law.m2"),
        ({"params": ActuatorParams(k2=np.full(SHAPE, -1e-6))}, "not positive"),
        ({"compensation": CompensationParams(coupling=0.5)}, "coupling"),
        ({"observer": ObserverGains(kp=0.8, ki=0.8)}, "observer"),
        ({"observer": ObserverGains(iterations=0)}, "observer.iterations"),
        ({"observer": ObserverGains(tolerance=-1e-4)}, "observer.tolerance"),
        ({"observer": ObserverGains(tolerance=float("nan"))}, "observer.tolerance"),
        ({"observer": ObserverGains(tolerance=2.0)}, "observer.tolerance"),
    ],
)
def test_invalid_configurations_are_rejected_with_a_reason(change: dict, match: str) -> None:
    config = FeedforwardConfig(shape=SHAPE, **{"params": PARAMS, **change})
    assert match in (config.reason_to_reject() or "")
    with pytest.raises(ValueError, match=match):
        Feedforward(config)


def test_reconfiguration_keeps_the_state_of_the_same_grid() -> None:
    ff = make(Mode.INVERSE_HYPERBOLIC)
    z = setpoints(9, 100 * NM)
    first = ff.command(z, 0.0)
    quadratic = Feedforward(
        FeedforwardConfig(shape=SHAPE, params=PARAMS, mode=Mode.INVERSE_QUADRATIC), previous=ff
    )
    # temperature carried over: commands go on without waiting for a new estimate
    result = quadratic.command(z, 0.01)
    assert not result.held
    z_plant = quadratic_forward(result.voltage, TEMPERATURE, PARAMS)
    assert np.max(np.abs(z_plant - z)) < 0.01 * NM
    np.testing.assert_array_equal(quadratic.last_voltage, result.voltage)
    assert not np.array_equal(result.voltage, first.voltage)


def test_switching_to_the_observer_is_bumpless() -> None:
    ff = make(Mode.INVERSE_HYPERBOLIC)
    z = setpoints(11, 150 * NM)
    ff.command(z, 0.0)
    observer = Feedforward(
        FeedforwardConfig(
            shape=SHAPE, params=PARAMS, mode=Mode.OBSERVER, observer=ObserverGains(iterations=1)
        ),
        previous=ff,
    )
    # the integrator starts at the command being applied: already on target
    first = observer.command(z, 0.01)
    z_plant = hyperbolic_forward(first.voltage, TEMPERATURE, PARAMS)
    assert np.max(np.abs(z_plant - z)) < 0.01 * NM


def test_a_candidate_configuration_leaves_the_running_one_untouched() -> None:
    ff = make(Mode.INVERSE_HYPERBOLIC)
    z = setpoints(12, 100 * NM)
    before = ff.command(z, 0.0).voltage.copy()
    # built (e.g. while validating a parameter set) and then discarded
    Feedforward(
        FeedforwardConfig(
            shape=SHAPE,
            params=PARAMS,
            compensation=CompensationParams(delay_s=0.5, hysteresis_weight=0.5),
        ),
        previous=ff,
    )
    np.testing.assert_array_equal(ff.command(z, 0.001).voltage, before)
    np.testing.assert_array_equal(
        ff.command(z * 1.1, 0.002).voltage,
        make(Mode.INVERSE_HYPERBOLIC).command(z * 1.1, 0.0).voltage,
    )
