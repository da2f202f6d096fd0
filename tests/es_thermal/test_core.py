"""Pure cores of es_thermal: interpolation, low-pass bank, network, Kalman gain."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg

from es_thermal.evaluation import score
from es_thermal.interpolation import (
    actuator_positions,
    block_centre_positions,
    interpolation_matrix,
    sampling_matrix,
    sensor_positions,
)
from es_thermal.kalman import KalmanTuning, ModelEstimator
from es_thermal.lowpass import LowpassBank
from es_thermal.modal import discretise, steady_state_covariance
from es_thermal.network import NetworkParams, continuous_model, grid_laplacian


def test_block_centres_cover_grid_including_cut_blocks() -> None:
    pos = block_centre_positions(5, 4, 2)
    assert pos.tolist() == [
        [0.5, 0.5], [0.5, 2.5], [2.5, 0.5], [2.5, 2.5], [4.0, 0.5], [4.0, 2.5],
    ]  # fmt: skip
    np.testing.assert_array_equal(block_centre_positions(3, 2, 1), actuator_positions(3, 2))


def test_sensor_positions_validation() -> None:
    np.testing.assert_array_equal(sensor_positions(2, 3, [], []), actuator_positions(2, 3))
    with pytest.raises(ValueError, match="outside"):
        sensor_positions(2, 3, [0.5, 2.0], [0.0, 1.0])
    with pytest.raises(ValueError, match="entries"):
        sensor_positions(2, 3, [0.5], [0.0, 1.0])
    with pytest.raises(ValueError, match="finite"):
        sensor_positions(2, 3, [np.nan], [0.0])


def test_sampling_is_bilinear_and_identity_on_actuators() -> None:
    rows, cols = 4, 5
    field = 3.0 + 0.5 * actuator_positions(rows, cols) @ np.array([1.0, -2.0])
    pos = np.array([[0.5, 0.5], [2.25, 3.75], [3.0, 4.0], [0.0, 2.0]])
    S = sampling_matrix(rows, cols, pos)
    np.testing.assert_allclose(S.sum(axis=1), 1.0)
    np.testing.assert_allclose(S @ field, 3.0 + 0.5 * (pos[:, 0] - 2.0 * pos[:, 1]))
    np.testing.assert_array_equal(
        sampling_matrix(rows, cols, actuator_positions(rows, cols)), np.eye(rows * cols)
    )


def test_interpolation_linear_inside_nearest_outside_and_masks() -> None:
    rows, cols = 6, 6
    pos = block_centre_positions(rows, cols, 2)
    plane = 1.0 + pos @ np.array([0.3, 0.7])
    W = interpolation_matrix(rows, cols, pos).toarray()
    np.testing.assert_allclose(W.sum(axis=1), 1.0)
    out = (W @ plane).reshape(rows, cols)
    targets = actuator_positions(rows, cols).reshape(rows, cols, 2)
    inside = (targets[..., 0] >= 0.5) & (targets[..., 0] <= 4.5) & (targets[..., 1] >= 0.5) & (
        targets[..., 1] <= 4.5
    )
    np.testing.assert_allclose(out[inside], (1.0 + targets @ np.array([0.3, 0.7]))[inside])
    assert out[0, 0] == pytest.approx(plane[0])  # corner: the nearest sensor
    valid = np.ones(len(pos), bool)
    valid[4] = False
    W2 = interpolation_matrix(rows, cols, pos, valid).toarray()
    assert np.all(W2[:, 4] == 0.0)
    np.testing.assert_allclose(W2.sum(axis=1), 1.0)
    one = np.zeros(len(pos), bool)
    one[2] = True
    np.testing.assert_array_equal(
        interpolation_matrix(rows, cols, pos, one).toarray()[:, 2], 1.0
    )
    with pytest.raises(ValueError, match="no valid sensor"):
        interpolation_matrix(rows, cols, pos, np.zeros(len(pos), bool))


def test_lowpass_starts_steady_attenuates_and_holds() -> None:
    fs = 10.0
    bank = LowpassBank(2, 1.0 / fs, cutoff_hz=0.1, order=2)
    t = np.arange(600) / fs
    signal = np.stack([40.0 + np.sin(2 * np.pi * 1.0 * t), np.full_like(t, 41.0)], axis=1)
    out = np.array([bank.step(x, np.array([True, True])) for x in signal])
    np.testing.assert_allclose(out[:, 1], 41.0)  # steady start: no transient from zero
    ripple = np.ptp(out[300:, 0]) / 2
    assert ripple < 0.02  # 1 Hz, a decade above a 2nd-order 0.1 Hz cut-off: about -40 dB
    held = bank.step(np.array([np.nan, 99.0]), np.array([False, True]))
    assert held[0] == pytest.approx(out[-1, 0], abs=1e-3)
    assert held[1] > 41.0
    with pytest.raises(ValueError, match="Nyquist"):
        LowpassBank(1, 1.0 / fs, cutoff_hz=6.0, order=2)


def test_laplacian_and_single_cell_steady_state() -> None:
    lap = grid_laplacian(3, 4).toarray()
    np.testing.assert_allclose(lap.sum(axis=1), 0.0)
    assert lap[0, 0] == 2 and lap[5, 5] == 4
    p = NetworkParams()
    A, B, H, layout = continuous_model(p, 1, 1, np.ones((1, 1)), sensor_tau=3.0)
    # Equilibrium with base 40 degC and 10 mW: T_a = T_b + P/G_ab, T_f = T_a + P/G_fa.
    power = 0.01
    x_free = np.linalg.solve(A[:-1, :-1], -(B[:-1, 0] * power + A[:-1, -1] * 40.0))
    t_act = 40.0 + power / p.actuator_to_base
    np.testing.assert_allclose(x_free, [t_act + power / p.face_to_actuator, t_act, t_act])
    assert layout.size == 4 and H[0, layout.sensor].tolist() == [1.0]


def test_doubling_matches_scipy_dare() -> None:
    pos = block_centre_positions(4, 4, 2)
    A, B, H, _ = continuous_model(NetworkParams(), 4, 4, sampling_matrix(4, 4, pos), 2.0)
    A_d, _ = discretise(A, B, 0.1)
    Q = np.diag(np.r_[np.full(32, 1e-6), np.full(4, 1e-12), 1e-5])
    R = 1e-4 * np.eye(4)
    P = steady_state_covariance(A_d, H, Q, R)
    reference = linalg.solve_discrete_are(A_d.T, H.T, Q, R)
    np.testing.assert_allclose(P, reference, rtol=1e-8, atol=1e-12)


def test_discretise_matches_matrix_exponential() -> None:
    A = np.array([[-1.0, 0.5], [0.2, -0.3]])
    B = np.array([[1.0], [0.0]])
    A_d, B_d = discretise(A, B, 0.5)
    np.testing.assert_allclose(A_d, linalg.expm(0.5 * A))
    np.testing.assert_allclose(B_d, np.linalg.solve(A, (A_d - np.eye(2)) @ B))


def test_model_estimator_requires_state_and_tracks_noise_free_model() -> None:
    rows = cols = 3
    params = NetworkParams().time_scaled(0.05)
    est = ModelEstimator(
        rows,
        cols,
        actuator_positions(rows, cols),
        params=params,
        sensor_tau=0.0,
        sample_period=0.1,
        tuning=KalmanTuning(),
    )
    with pytest.raises(ValueError, match="no state"):
        est.actuator_temperatures()
    est.initialise(np.full(9, 40.0), np.full(9, 40.0), np.ones(9, bool))
    assert est.base_temperature == pytest.approx(40.0)
    # No heat, readings at equilibrium: the estimate stays put.
    for _ in range(50):
        est.predict(np.zeros(9))
        est.correct(np.full(9, 40.0), np.ones(9, bool))
    np.testing.assert_allclose(est.actuator_temperatures(), 40.0, atol=1e-9)
    assert all(abs(b) < 1e-9 for b in est.biases.values())


@pytest.mark.parametrize(
    ("positions", "tau"),
    [
        (block_centre_positions(4, 6, 2), 0.5),  # regular: solved mode group by mode group
        (actuator_positions(4, 6), 0.0),  # one per actuator
        (np.array([[0.0, 0.0], [1.5, 2.2], [3.0, 5.0], [2.0, 1.0]]), 0.5),  # irregular: dense
    ],
)
def test_modal_gain_equals_dense_solution(positions: np.ndarray, tau: float) -> None:
    rows, cols, dt = 4, 6, 0.1
    params = NetworkParams().time_scaled(0.05)
    tuning = KalmanTuning()
    est = ModelEstimator(
        rows, cols, positions, params=params, sensor_tau=tau, sample_period=dt, tuning=tuning
    )
    sampling = sampling_matrix(rows, cols, positions)
    A, B, H, layout = continuous_model(params, rows, cols, sampling, tau)
    A_d, _ = discretise(A, B, dt)
    q = np.zeros(layout.size)
    q[: 2 * layout.cells] = tuning.process_noise**2
    q[layout.sensor] = (1e-3 * tuning.process_noise) ** 2
    q[layout.base] = tuning.base_drift**2
    R = tuning.sensor_noise**2 * np.eye(len(positions))
    P = steady_state_covariance(A_d, H, np.diag(q * dt), R)
    gain = np.linalg.solve(H @ P @ H.T + R, H @ P).T
    np.testing.assert_allclose(est.gain_matrix(), gain, atol=1e-9)


def test_score_finds_the_lag_and_skips_missing_estimates() -> None:
    t = np.arange(200) * 0.1
    truth = (40.0 + np.sin(0.5 * t))[:, None, None] * np.ones((1, 2, 2))
    late = np.roll(truth, 7, axis=0)  # the estimate shows the truth 0.7 s late
    late[:7] = np.nan  # no estimate yet
    stats = score(late, truth, 0.1, skip=10)
    assert stats.lag == pytest.approx(0.7)
    assert stats.samples == 190
    assert stats.rms > 0.1
    assert score(truth, truth, 0.1).rms == 0.0
    with pytest.raises(ValueError, match="no estimate"):
        score(np.full_like(truth, np.nan), truth, 0.1)
