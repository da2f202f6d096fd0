"""The model estimator's fast path: separable transforms, modal sampling, batched solution."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from es_thermal.interpolation import actuator_positions, block_centre_positions, sampling_matrix
from es_thermal.kalman import KalmanTuning, ModelEstimator
from es_thermal.modal import discretise, modal_solution, steady_state_covariance
from es_thermal.network import (
    DENSE_TRANSFORM_MAX,
    GridTransform,
    NetworkParams,
    continuous_model,
    dct_matrix,
    modal_sampling,
    sensor_transform,
)

IRREGULAR = np.array([[0.0, 0.0], [1.5, 2.2], [3.0, 5.0], [2.0, 1.0], [4.0, 6.0]])


@pytest.mark.parametrize(("rows", "cols"), [(3, 5), (17, 19)], ids=["formed", "fft"])
def test_grid_transform_applies_the_kronecker_product(rows: int, cols: int) -> None:
    full = np.kron(dct_matrix(rows), dct_matrix(cols))
    t = GridTransform.dct(rows, cols)
    assert (t.dense is None) == (rows * cols > DENSE_TRANSFORM_MAX)
    x = np.random.default_rng(0).standard_normal((rows * cols, 2))
    np.testing.assert_allclose(t.forward(x), full @ x, atol=1e-13)
    np.testing.assert_allclose(t.inverse(x[:, 0]), full.T @ x[:, 0], atol=1e-13)
    np.testing.assert_allclose(t.inverse(t.forward(x)), x, atol=1e-13)
    index = np.array([0, 4, 7, rows * cols - 1])
    np.testing.assert_allclose(t.columns(index), full[:, index], atol=1e-15)
    eye = GridTransform.eye(4)
    y = np.arange(4.0)
    out = eye.forward(y)
    np.testing.assert_array_equal(out, y)
    out[0] = 9.0
    assert y[0] == 0.0  # a copy, not a view


@pytest.mark.parametrize(
    "positions",
    [block_centre_positions(5, 7, 2), actuator_positions(5, 7), IRREGULAR],
    ids=["blocks-with-cut-edges", "one-per-actuator", "irregular"],
)
def test_modal_sampling_equals_the_dense_product(positions: np.ndarray) -> None:
    rows, cols = 5, 7
    sensors = sensor_transform(positions)
    expected = (
        np.kron(sensors.row, sensors.col)
        @ sampling_matrix(rows, cols, positions)
        @ np.kron(dct_matrix(rows), dct_matrix(cols)).T
    )
    got = modal_sampling(rows, cols, positions, sensors)
    assert sparse.issparse(got)
    np.testing.assert_allclose(got.toarray(), expected, atol=1e-12)
    assert sensors.identity == (positions is IRREGULAR)


def test_batched_riccati_and_discretisation_equal_one_by_one() -> None:
    rng = np.random.default_rng(3)
    count, n = 5, 3
    A = -np.eye(n) + 0.3 * rng.standard_normal((count, n, n))
    B = rng.standard_normal((count, n, 1))
    Ad, Bd = discretise(A, B, 0.2)
    H = rng.standard_normal((count, 2, n))
    Q = np.broadcast_to(1e-3 * np.eye(n), (count, n, n)).copy()
    R = np.broadcast_to(1e-2 * np.eye(2), (count, 2, 2)).copy()
    P = steady_state_covariance(Ad, H, Q, R)
    for k in range(count):
        one_a, one_b = discretise(A[k], B[k], 0.2)
        np.testing.assert_allclose(Ad[k], one_a, rtol=1e-12)
        np.testing.assert_allclose(Bd[k], one_b, rtol=1e-12)
        np.testing.assert_allclose(
            P[k], steady_state_covariance(Ad[k], H[k], Q[k], R[k]), rtol=1e-10, atol=1e-15
        )


def test_modal_solution_of_a_block_diagonal_system_is_sparse_and_exact() -> None:
    blocks = [np.array([[-1.0, 0.5], [0.0, -2.0]]), np.array([[-0.5]]), np.array([[-3.0]])]
    A = sparse.block_diag(blocks, format="csr")
    B = sparse.csr_matrix(np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0], [0.0, 0.0]]))
    H = sparse.csr_matrix(np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]))
    q = np.full(4, 1e-3)
    sol = modal_solution(A, B, H, q=q, r=1e-2, dt=0.1)
    Ad, Bd = discretise(A.toarray(), B.toarray(), 0.1)
    np.testing.assert_allclose(sol.A_d.toarray(), Ad, atol=1e-15)
    np.testing.assert_allclose(sol.B_d.toarray(), Bd, atol=1e-15)
    # The last state is neither observed nor driven: it has no gain, but it is discretised.
    assert sol.gain.toarray()[3].tolist() == [0.0, 0.0]
    assert sol.A_d[3, 3] == pytest.approx(np.exp(-0.3))
    Hd = H.toarray()
    P = steady_state_covariance(Ad[:3, :3], Hd[:, :3], 1e-3 * np.eye(3), 1e-2 * np.eye(2))
    cov = Hd[:, :3] @ P @ Hd[:, :3].T + 1e-2 * np.eye(2)
    np.testing.assert_allclose(sol.innovation_cov.toarray(), cov, rtol=1e-10)
    np.testing.assert_allclose(
        sol.gain.toarray()[:3], np.linalg.solve(cov, Hd[:, :3] @ P).T, rtol=1e-9, atol=1e-15
    )


@pytest.mark.parametrize(
    ("positions", "tau"),
    [(block_centre_positions(4, 6, 2), 0.5), (actuator_positions(4, 6), 0.0), (IRREGULAR, 0.5)],
    ids=["blocks-lag", "one-per-actuator", "irregular-lag"],
)
def test_modal_filter_runs_like_the_grid_filter(positions: np.ndarray, tau: float) -> None:
    """Predict/correct in modes equal the textbook filter in grid coordinates."""
    rows, cols, dt = 4, 6, 0.1
    params = NetworkParams().time_scaled(0.05)
    tuning = KalmanTuning(bias_prior=1e-9)  # model-error fit pinned at zero: state only
    est = ModelEstimator(
        rows, cols, positions, params=params, sensor_tau=tau, sample_period=dt, tuning=tuning
    )
    sampling = sampling_matrix(rows, cols, positions)
    A, B, H, layout = continuous_model(params, rows, cols, sampling, tau)
    A_d, B_d = discretise(A, B, dt)
    gain = est.gain_matrix()
    rng = np.random.default_rng(1)
    s = len(positions)
    field = 40.0 + rng.standard_normal(rows * cols)
    readings = sampling @ field + 0.1
    valid = np.ones(s, bool)
    valid[1] = False
    est.initialise(field, readings, valid)
    x = np.r_[field, field, np.where(valid, readings, sampling @ field)[: layout.sensors], 0.0]
    x[layout.base] = np.mean(readings[valid])
    for k in range(25):
        heat = 0.01 * rng.random(rows * cols)
        steps = 2 if k == 7 else 1
        est.predict(heat, steps)
        for _ in range(steps):
            x = A_d @ x + B_d @ heat
        readings = 41.0 + 0.5 * rng.standard_normal(s)
        valid = rng.random(s) > 0.2
        innovation = est.correct(readings, valid)
        expected = np.where(valid, readings - H @ x, 0.0)
        np.testing.assert_allclose(innovation, expected, atol=1e-9)
        x = x + gain @ expected
        np.testing.assert_allclose(est.actuator_temperatures(), x[layout.actuator], atol=1e-9)
    assert est.base_temperature == pytest.approx(x[layout.base], abs=1e-9)
