"""Model library: round trips, slopes, thesis numbers, domains and per-actuator maps."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar

from es_physics.laws import (
    DEFAULT_V_LIMIT,
    CompiledLaws,
    Status,
    d_max,
    hyperbolic_forward,
    hyperbolic_inverse,
    hyperbolic_slope,
    quadratic_forward,
    quadratic_inverse,
    v_max,
    z_sat,
)
from es_physics.params import THESIS_INTERVALS_95, ActuatorParams

THESIS = ActuatorParams.thesis()
# the operating band: every law inside the 95 % intervals stays positive there
temperatures = st.floats(40.0, 52.0)
voltages = st.floats(1e-3, DEFAULT_V_LIMIT * 0.999)


def perturbed(draw_fraction: float) -> ActuatorParams:
    """Parameters moved inside the thesis's 95 % intervals (fraction 0 = low end, 1 = high)."""
    values = {
        name: low + draw_fraction * (high - low)
        for name, (low, high) in THESIS_INTERVALS_95.items()
    }
    return ActuatorParams(**values)


@settings(max_examples=300, deadline=None)
@given(V=voltages, T=temperatures, fraction=st.floats(0.0, 1.0), curvature=st.floats(-1.0, 1.0))
def test_hyperbolic_round_trip(V: float, T: float, fraction: float, curvature: float) -> None:
    # quadratic laws (m3, k3) as well: small enough to keep M, k positive over the range
    params = replace(perturbed(fraction), m3=curvature * 1e-19, k3=curvature * 2e-11)
    z = hyperbolic_forward(V, T, params)
    result = hyperbolic_inverse(z, T, params)
    assert result.status == Status.OK
    assert result.voltage == pytest.approx(V, rel=1e-12)


@settings(max_examples=200, deadline=None)
@given(V=voltages, T=st.floats(40.0, 68.0))
def test_hyperbolic_round_trip_over_the_whole_validity_range(V: float, T: float) -> None:
    result = hyperbolic_inverse(hyperbolic_forward(V, T, THESIS), T, THESIS)
    assert result.status == Status.OK
    assert result.voltage == pytest.approx(V, rel=1e-12)


@settings(max_examples=300, deadline=None)
@given(V=voltages, T=temperatures, fraction=st.floats(0.0, 1.0))
def test_quadratic_round_trip(V: float, T: float, fraction: float) -> None:
    params = perturbed(fraction)
    z = quadratic_forward(V, T, params)
    result = quadratic_inverse(z, T, params)
    assert result.status == Status.OK
    assert result.voltage == pytest.approx(V, rel=1e-12)


@pytest.mark.parametrize("T", [40.0, 44.5, 52.0, 60.0])
def test_d_max_and_v_max_match_a_numeric_maximisation(T: float) -> None:
    found = minimize_scalar(
        lambda V: -hyperbolic_slope(V, T, THESIS),
        bounds=(1.0, 400.0),
        method="bounded",
        options={"xatol": 1e-9},
    )
    assert float(v_max(T, THESIS)) == pytest.approx(found.x, rel=1e-6)
    assert float(d_max(T, THESIS)) == pytest.approx(-found.fun, rel=1e-9)
    # at V_max the displacement is exactly z_sat / 3
    z_at = hyperbolic_forward(v_max(T, THESIS), T, THESIS)
    assert z_at == pytest.approx(z_sat(T, THESIS) / 3.0, rel=1e-12)


def test_thesis_numbers() -> None:
    assert float(d_max(40.0, THESIS)) == pytest.approx(0.966e-9, rel=0.01)
    assert float(z_sat(40.0, THESIS)) == pytest.approx(221e-9, rel=0.01)
    T = np.linspace(40.0, 52.0, 25)
    np.testing.assert_allclose(v_max(T, THESIS), 2.54 * T + 16.5, rtol=0.05)


def test_hyperbolic_inverse_domains_and_statuses() -> None:
    T = 45.0
    reach = float(hyperbolic_forward(DEFAULT_V_LIMIT, T, THESIS))
    z = np.array([-1e-9, 0.0, 50e-9, reach * 1.0001, float(z_sat(T, THESIS)) * 2, np.nan, np.inf])
    result = hyperbolic_inverse(z, T, THESIS)
    assert result.status.tolist() == [
        Status.CLIPPED_LOW,
        Status.OK,
        Status.OK,
        Status.CLIPPED_HIGH,
        Status.CLIPPED_HIGH,
        Status.INVALID,
        Status.INVALID,
    ]
    assert result.voltage.tolist()[:2] == [0.0, 0.0]
    assert result.voltage[3] == result.voltage[4] == DEFAULT_V_LIMIT
    assert result.voltage[5] == result.voltage[6] == 0.0
    assert np.all(np.isfinite(result.voltage))


def test_temperatures_outside_validity_are_clamped_and_flagged() -> None:
    T = np.array([20.0, 39.0, 45.0, 90.0, np.nan, -np.inf])
    result = hyperbolic_inverse(50e-9, T, THESIS)
    assert result.status.tolist() == [
        Status.OUT_OF_VALIDITY,
        Status.OUT_OF_VALIDITY,
        Status.OK,
        Status.OUT_OF_VALIDITY,
        Status.INVALID,
        Status.INVALID,
    ]
    # evaluated at the nearest bound of the range [Tm + 2, Tm + 30]
    low, high = THESIS.validity_range()
    assert result.voltage[0] == pytest.approx(hyperbolic_inverse(50e-9, low, THESIS).voltage)
    assert result.voltage[3] == pytest.approx(hyperbolic_inverse(50e-9, high, THESIS).voltage)
    assert result.voltage[4] == result.voltage[5] == 0.0


def test_quadratic_inverse_clips_at_the_voltage_limit() -> None:
    z = quadratic_forward(np.array([100.0, 400.0]), 45.0, THESIS)
    result = quadratic_inverse(z, 45.0, THESIS, v_limit=300.0)
    assert result.voltage.tolist() == pytest.approx([100.0, 300.0])
    assert result.status.tolist() == [Status.OK, Status.CLIPPED_HIGH]


def test_grid_with_per_actuator_maps_equals_element_by_element() -> None:
    rng = np.random.default_rng(3)
    shape = (4, 5)
    params = ActuatorParams(
        L=rng.uniform(0.18e-3, 0.22e-3, shape),
        Tm=rng.uniform(36.0, 40.0, shape),
        m1=rng.uniform(-48e-18, -35e-18, shape),
        m2=rng.uniform(1170e-18, 1840e-18, shape),
        k1=rng.uniform(-20.7e-9, -15e-9, shape),
        k2=rng.uniform(1052.5e-9, 1322.5e-9, shape),
        k3=rng.uniform(-1e-11, 1e-11, shape),
    )
    T = rng.uniform(35.0, 55.0, shape)
    z = rng.uniform(-10e-9, 240e-9, shape)
    grid = hyperbolic_inverse(z, T, params)
    grid_q = quadratic_inverse(z, T, params)
    for index in np.ndindex(shape):
        one = params.select(index)
        single = hyperbolic_inverse(z[index], T[index], one)
        assert grid.voltage[index] == single.voltage
        assert grid.status[index] == single.status
        assert grid_q.voltage[index] == quadratic_inverse(z[index], T[index], one).voltage
        assert hyperbolic_forward(grid.voltage, T, params)[index] == pytest.approx(
            hyperbolic_forward(single.voltage, T[index], one), rel=1e-15
        )


def test_elements_whose_law_is_not_positive_at_their_temperature_are_invalid() -> None:
    # k(T*) = k2 + k1 T* crosses zero at T* = 23.35 degC (T = 61.35 degC) with this slope
    params = ActuatorParams(k1=np.array([-17.375e-9, -50e-9, -50e-9]))
    compiled = CompiledLaws(params, (3,))
    assert compiled.usable.tolist() == [True, False, False]
    laws = compiled.at(np.array([62.0, 45.0, 62.0]))
    assert laws.status.tolist() == [Status.OK, Status.OK, Status.INVALID]
    result = laws.hyperbolic_inverse(np.full(3, 50e-9), DEFAULT_V_LIMIT)
    assert result.status.tolist() == [Status.OK, Status.OK, Status.INVALID]
    assert result.voltage[2] == 0.0
    assert result.voltage[1] == pytest.approx(
        hyperbolic_inverse(50e-9, 45.0, params.select(1)).voltage
    )


def test_laws_at_temperature_match_the_functions() -> None:
    T = np.array([41.0, 47.0, 51.0])
    laws = CompiledLaws(THESIS, (3,)).at(T)
    np.testing.assert_allclose(laws.z_sat, z_sat(T, THESIS), rtol=1e-14)
    np.testing.assert_allclose(laws.d_max, d_max(T, THESIS), rtol=1e-14)
    np.testing.assert_allclose(laws.v_max, v_max(T, THESIS), rtol=1e-14)
    V = np.array([10.0, 120.0, 300.0])
    np.testing.assert_allclose(laws.hyperbolic_forward(V), hyperbolic_forward(V, T, THESIS))
    np.testing.assert_allclose(laws.hyperbolic_slope(V), hyperbolic_slope(V, T, THESIS))
    np.testing.assert_allclose(laws.quadratic_forward(V), quadratic_forward(V, T, THESIS))


@settings(max_examples=60, deadline=None)
@given(
    T=st.lists(st.floats(20.0, 80.0) | st.just(np.nan), min_size=4, max_size=4),
    z=st.lists(st.floats(-1e-8, 3e-7) | st.just(np.inf), min_size=4, max_size=4),
    steep=st.booleans(),
)
def test_fused_kernel_equals_the_general_path(T: list[float], z: list[float], steep: bool) -> None:
    # steep: one actuator's k(T) turns negative inside the validity range
    k1 = np.array([-17e-9, -18e-9, -60e-9 if steep else -16e-9, -17.5e-9])
    compiled = CompiledLaws(ActuatorParams(k1=k1), (4,))
    fused = compiled.hyperbolic_inverse(np.array(z), np.array(T))
    general = compiled.at(np.array(T)).hyperbolic_inverse(np.array(z), DEFAULT_V_LIMIT)
    np.testing.assert_array_equal(fused.status, general.status)
    np.testing.assert_allclose(fused.voltage, general.voltage, rtol=1e-14)
