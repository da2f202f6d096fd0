"""Thermal network, illumination, exposure schedule and base profile of the plant core."""

from __future__ import annotations

import numpy as np
import pytest

from es_sim_plant.thermal import (
    BaseProfile,
    ExposureSchedule,
    Illumination,
    ThermalNetwork,
    ThermalParams,
    dct_matrix,
)


def dense_network(shape: tuple[int, int], p: ThermalParams) -> tuple[np.ndarray, np.ndarray]:
    """Return (A, B) of dx/dt = A x + B [P; Q; T_b], x = [T_f; T_a], cell by cell."""
    rows, cols = shape
    n = rows * cols
    A = np.zeros((2 * n, 2 * n))
    B = np.zeros((2 * n, 2 * n + 1))
    for r in range(rows):
        for c in range(cols):
            i = r * cols + c
            f, a = i, n + i
            A[f, f] -= p.face_to_actuator / p.face_capacitance
            A[f, a] += p.face_to_actuator / p.face_capacitance
            A[a, a] -= (p.face_to_actuator + p.actuator_to_base) / p.actuator_capacitance
            A[a, f] += p.face_to_actuator / p.actuator_capacitance
            B[f, i] = 1.0 / p.face_capacitance
            B[a, n + i] = 1.0 / p.actuator_capacitance
            B[a, 2 * n] = p.actuator_to_base / p.actuator_capacitance
            for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
                if 0 <= rr < rows and 0 <= cc < cols:
                    j = rr * cols + cc
                    A[f, f] -= p.face_lateral / p.face_capacitance
                    A[f, j] += p.face_lateral / p.face_capacitance
                    A[a, a] -= p.actuator_lateral / p.actuator_capacitance
                    A[a, n + j] += p.actuator_lateral / p.actuator_capacitance
    return A, B


@pytest.fixture
def params() -> ThermalParams:
    return ThermalParams()


def test_steady_state_matches_dense_analytic_solution(params: ThermalParams) -> None:
    shape = (3, 4)
    rng = np.random.default_rng(3)
    power = rng.uniform(0.0, 0.02, shape)
    heat = rng.uniform(0.0, 0.005, shape)
    base = 43.5
    A, B = dense_network(shape, params)
    u = np.concatenate([power.ravel(), heat.ravel(), [base]])
    x = np.linalg.solve(A, -B @ u)
    net = ThermalNetwork(shape, params, dt=0.01, initial_temperature=base)
    face, act = net.steady_state(power, heat, base)
    np.testing.assert_allclose(face.ravel(), x[:12], rtol=0, atol=1e-9)
    np.testing.assert_allclose(act.ravel(), x[12:], rtol=0, atol=1e-9)
    # Stepping long enough with held inputs converges to the same equilibrium.
    long_net = ThermalNetwork(shape, params, dt=50.0, initial_temperature=base)
    for _ in range(200):
        long_net.step(power, heat, base)
    face_t, act_t = long_net.temperatures()
    np.testing.assert_allclose(act_t.ravel(), x[12:], atol=1e-7)
    np.testing.assert_allclose(face_t.ravel(), x[:12], atol=1e-7)


def test_uniform_heat_closed_form(params: ThermalParams) -> None:
    shape = (4, 5)
    power = np.full(shape, 0.01)
    net = ThermalNetwork(shape, params, dt=0.01, initial_temperature=40.0)
    face, act = net.steady_state(power, None, 40.0)
    np.testing.assert_allclose(act, 40.0 + 0.01 / params.actuator_to_base, atol=1e-9)
    np.testing.assert_allclose(face, act + 0.01 / params.face_to_actuator, atol=1e-9)


def test_step_is_exact_zero_order_hold(params: ThermalParams) -> None:
    shape = (3, 3)
    power = np.zeros(shape)
    power[0, 1] = 0.03
    coarse = ThermalNetwork(shape, params, dt=1.0, initial_temperature=42.0)
    fine = ThermalNetwork(shape, params, dt=0.1, initial_temperature=42.0)
    for _ in range(5):
        coarse.step(power, None, 44.0)
        for _ in range(10):
            fine.step(power, None, 44.0)
    np.testing.assert_allclose(coarse.temperatures()[1], fine.temperatures()[1], atol=1e-10)
    # ... and agrees with the dense continuous-time solution (matrix exponential).
    import scipy.linalg

    A, B = dense_network(shape, params)
    u = np.concatenate([power.ravel(), np.zeros(9), [44.0]])
    x0 = np.full(18, 42.0)
    x_inf = np.linalg.solve(A, -B @ u)
    x5 = x_inf + scipy.linalg.expm(A * 5.0) @ (x0 - x_inf)
    np.testing.assert_allclose(coarse.temperatures()[1].ravel(), x5[9:], atol=1e-9)


def test_dct_matrix_diagonalises_path_laplacian() -> None:
    n = 6
    d = dct_matrix(n)
    np.testing.assert_allclose(d @ d.T, np.eye(n), atol=1e-12)
    lap = np.diag([1.0] + [2.0] * (n - 2) + [1.0]) - np.eye(n, k=1) - np.eye(n, k=-1)
    diag = d @ lap @ d.T
    np.testing.assert_allclose(diag, np.diag(np.diag(diag)), atol=1e-12)


def test_default_time_constants_span_seconds_to_minutes(params: ThermalParams) -> None:
    taus = ThermalNetwork((12, 12), params, 0.01, 42.0).time_constants()
    assert taus.max() > 60.0
    assert taus.min() < 10.0
    scaled = ThermalNetwork((12, 12), params.time_scaled(0.05), 0.01, 42.0).time_constants()
    np.testing.assert_allclose(scaled, taus * 0.05, rtol=1e-9)


@pytest.mark.parametrize("pattern", ["uniform", "dipole", "quadrupole", "off_axis_spot", "annular"])
def test_illumination_sums_to_total_power(pattern: str) -> None:
    power = Illumination(pattern=pattern, total_power_w=2.0).power_map((12, 12))
    assert power.sum() == pytest.approx(2.0)
    assert np.all(power > 0.0)


def test_illumination_patterns_have_their_shape() -> None:
    shape = (12, 12)
    dipole = Illumination(pattern="dipole", background=0.0).power_map(shape)
    np.testing.assert_allclose(dipole, dipole[:, ::-1], rtol=1e-12)  # two poles along x
    assert dipole[6, 6] < 0.5 * dipole.max()
    quad = Illumination(pattern="quadrupole", background=0.0).power_map(shape)
    np.testing.assert_allclose(quad, quad.T, rtol=1e-12)
    spot = Illumination(pattern="off_axis_spot", spot_x=0.5, spot_y=-0.5, sigma=0.1)
    r, c = np.unravel_index(np.argmax(spot.power_map(shape)), shape)
    assert (int(r), int(c)) in {(2, 8), (3, 8), (2, 9), (3, 9)}
    uniform = Illumination(pattern="uniform").power_map(shape)
    np.testing.assert_allclose(uniform, 1.0 / 144)
    with pytest.raises(ValueError, match="pattern"):
        Illumination(pattern="hexapole").validate()


def test_exposure_schedule_on_fraction() -> None:
    schedule = ExposureSchedule(start_s=1.0, exposure_s=2.0, swap_s=1.0, count=2)
    assert schedule.on_fraction(0.0, 1.0) == 0.0
    assert schedule.on_fraction(1.0, 3.0) == 1.0
    assert schedule.on_fraction(2.5, 3.5) == pytest.approx(0.5)
    assert schedule.on_fraction(4.0, 6.0) == 1.0
    assert schedule.on_fraction(7.0, 20.0) == 0.0  # after the second exposure
    forever = ExposureSchedule(start_s=0.0, exposure_s=2.0, swap_s=1.0)
    assert forever.on_fraction(0.0, 300.0) == pytest.approx(2.0 / 3.0)


def test_base_profile_step_and_linear() -> None:
    steps = BaseProfile(
        times=(0.0, 2.0, 4.0), temperatures=(40.0, 42.0, 44.0), interpolation="step"
    )
    assert steps.at(1.99) == 40.0
    assert steps.at(2.0) == 42.0
    assert steps.mean(1.0, 3.0) == pytest.approx(41.0)
    ramp = BaseProfile(times=(0.0, 10.0), temperatures=(41.0, 51.0))
    assert ramp.at(5.0) == pytest.approx(46.0)
    assert ramp.mean(0.0, 10.0) == pytest.approx(46.0)
    assert ramp.at(20.0) == 51.0
    with pytest.raises(ValueError, match="non-decreasing"):
        BaseProfile(times=(1.0, 0.0), temperatures=(40.0, 41.0)).validate()


def test_base_ramp_is_followed_by_actuator_with_lag(params: ThermalParams) -> None:
    profile = BaseProfile(times=(0.0, 100.0), temperatures=(40.0, 50.0))
    net = ThermalNetwork((1, 1), params, dt=2.0, initial_temperature=40.0)
    actuator = []
    for k in range(600):
        net.step(np.zeros((1, 1)), None, profile.mean(k * 2.0, (k + 1) * 2.0))
        actuator.append(float(net.temperatures()[1][0, 0]))
    assert actuator[49] < 50.0 - 0.5  # still lagging at the end of the ramp (t = 100 s)
    assert actuator[-1] == pytest.approx(50.0, abs=0.05)
