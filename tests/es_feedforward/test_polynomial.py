"""Polynomial (series) model: coefficients, agreement with tanh, numeric inverse, domains."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from es_feedforward.polynomial import (
    MAX_ORDER,
    peak_s,
    polynomial_forward,
    polynomial_inverse,
    polynomial_slope,
    series_coefficients,
)
from es_physics.laws import Status, hyperbolic_forward, hyperbolic_slope, z_sat
from es_physics.params import ActuatorParams

THESIS = ActuatorParams.thesis()
ORDERS = list(range(2, MAX_ORDER + 1, 2))


def test_series_coefficients_are_those_of_tanh_squared() -> None:
    assert series_coefficients(8) == pytest.approx([1.0, -2 / 3, 17 / 45, -62 / 315], rel=1e-15)
    # the full series converges to tanh^2 inside its radius pi/2
    y = np.linspace(0.0, 0.6, 7)
    a = series_coefficients(MAX_ORDER)
    series = sum(c * y ** (2 * (j + 1)) for j, c in enumerate(a))
    np.testing.assert_allclose(series, np.tanh(y) ** 2, rtol=1e-7, atol=1e-300)


@pytest.mark.parametrize("order", [0, 3, 22])
def test_unsupported_orders_are_rejected(order: int) -> None:
    with pytest.raises(ValueError, match="order"):
        series_coefficients(order)


@pytest.mark.parametrize("order", [6, 8, 12])
def test_series_and_tanh_forms_agree_for_small_u(order: int) -> None:
    T = 45.0
    u = np.linspace(0.0, 0.5, 51)
    V = u * THESIS.L / THESIS.k(T)
    z_series = polynomial_forward(V, T, THESIS, order)
    z_tanh = hyperbolic_forward(V, T, THESIS)
    # truncation error is of the order of the first dropped term
    dropped = abs(series_coefficients(order + 2)[-1]) * u ** (order + 2) * z_sat(T, THESIS)
    rounding = 8 * np.finfo(float).eps * z_tanh
    assert np.all(np.abs(z_series - z_tanh) <= 1.01 * dropped + rounding)
    assert np.max(np.abs(z_series - z_tanh)) < 5e-3 * z_tanh.max()
    # slope: the derivative of this forward model, close to the tanh slope at small u
    slope = polynomial_slope(V, T, THESIS, order)
    h = 1e-4
    numeric = (
        polynomial_forward(V + h, T, THESIS, order) - polynomial_forward(V - h, T, THESIS, order)
    ) / (2 * h)
    np.testing.assert_allclose(slope, numeric, rtol=1e-6, atol=1e-20)
    np.testing.assert_allclose(slope, hyperbolic_slope(V, T, THESIS), rtol=2e-2)


@settings(max_examples=300, deadline=None)
@given(
    order=st.sampled_from(ORDERS),
    reach=st.floats(1e-6, 0.9),
    T=st.floats(40.0, 68.0),
)
def test_polynomial_round_trip(order: int, reach: float, T: float) -> None:
    # valid domain: below the series' peak (where the truncation stops rising) and v_limit
    q = THESIS.k(T) / THESIS.L
    V_top = min(np.sqrt(peak_s(order)) / q, 350.0)
    V = reach * V_top
    result = polynomial_inverse(polynomial_forward(V, T, THESIS, order), T, THESIS, order=order)
    assert result.status == Status.OK
    assert result.voltage == pytest.approx(V, rel=1e-12)


def test_peak_of_the_truncated_series() -> None:
    # 1 - 2/3 s: z ~ s - 2 s^2 / 3 peaks at s = 3/4
    assert peak_s(4) == pytest.approx(0.75)
    assert peak_s(2) == np.inf
    assert peak_s(6) == np.inf  # 1 - 4/3 s + 17/15 s^2 has no real root


def test_polynomial_inverse_domains() -> None:
    T = 45.0
    q = THESIS.k(T) / THESIS.L
    V_peak = np.sqrt(peak_s(4)) / q
    beyond = float(polynomial_forward(V_peak, T, THESIS, 4)) * 1.01
    z = np.array([-1e-9, 0.0, 20e-9, beyond, np.nan])
    result = polynomial_inverse(z, np.array([T, T, T, T, T]), THESIS, order=4)
    assert result.status.tolist() == [
        Status.CLIPPED_LOW,
        Status.OK,
        Status.OK,
        Status.CLIPPED_HIGH,
        Status.INVALID,
    ]
    assert result.voltage[3] == pytest.approx(V_peak)
    assert result.voltage[[0, 1, 4]].tolist() == [0.0, 0.0, 0.0]
    # orders without a peak clip at v_limit
    high = polynomial_inverse(1e-3, T, THESIS, v_limit=200.0, order=6)
    assert high.voltage == 200.0
    assert high.status == Status.CLIPPED_HIGH
    # temperatures outside the laws' range
    out = polynomial_inverse(20e-9, np.array([30.0, np.nan]), THESIS)
    assert out.status.tolist() == [Status.OUT_OF_VALIDITY, Status.INVALID]


def test_polynomial_grid_with_per_actuator_maps_equals_element_by_element() -> None:
    rng = np.random.default_rng(5)
    shape = (3, 4)
    params = ActuatorParams(
        m2=rng.uniform(1170e-18, 1840e-18, shape), k2=rng.uniform(1052.5e-9, 1322.5e-9, shape)
    )
    T = rng.uniform(40.0, 52.0, shape)
    z = rng.uniform(0.0, 150e-9, shape)
    grid = polynomial_inverse(z, T, params)
    for index in np.ndindex(shape):
        single = polynomial_inverse(z[index], T[index], params.select(index))
        assert grid.voltage[index] == pytest.approx(single.voltage, rel=1e-14)
        assert grid.status[index] == single.status
