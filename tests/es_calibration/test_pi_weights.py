"""Prandtl-Ishlinskii weights by NNLS: non-negative by construction, the true operators found."""

from __future__ import annotations

import numpy as np
import pytest

from es_calibration.errors import CalibrationFitError
from es_calibration.search.playfit import best_operators, nonnegative_weights
from es_physics.effects.hysteresis import play


def _plays(V: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Play operators (n, K) of the sequence V, each starting at rest on V[0]."""
    out = np.empty((V.size, thresholds.size))
    state = np.full(thresholds.size, V[0])
    for i, v in enumerate(V):
        state = np.array([play(state[k], v, r) for k, r in enumerate(thresholds)])
        out[i] = state
    return out


def _normal(columns: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return columns.T @ columns, columns.T @ target


def test_three_operator_truth_is_recovered_from_a_threshold_grid() -> None:
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 20.0, 4000)
    V = 120.0 * np.sin(2 * np.pi * 0.3 * t) + 60.0 * np.sin(2 * np.pi * 1.1 * t + 0.4)
    grid = np.geomspace(2.0, 80.0, 16)
    truth_idx = (2, 8, 13)
    truth_w = np.array([0.05, 0.12, 0.08])
    gaps = _plays(V, grid) - V[:, None]  # play_i(V) - V: the columns of V_eff - V
    target = gaps[:, truth_idx] @ truth_w + 0.01 * rng.standard_normal(V.size)
    G, b = _normal(gaps, target)
    choices = best_operators(G, b, 3)
    assert [len(c[0]) for c in choices] == [1, 2, 3]
    subset, weights, change = choices[-1]
    assert subset == truth_idx
    assert np.all(weights > 0)
    np.testing.assert_allclose(weights, truth_w, rtol=0.02)
    # each extra operator lowers the sum of squares; three leave only the noise
    assert choices[0][2] > choices[1][2] > choices[2][2]
    assert target @ target + change == pytest.approx(0.01**2 * V.size, rel=0.1)


def test_weights_stay_non_negative_where_least_squares_would_go_negative() -> None:
    rng = np.random.default_rng(2)
    C = rng.standard_normal((500, 3))
    target = C @ np.array([0.3, -0.2, 0.1])
    free = np.linalg.lstsq(C, target, rcond=None)[0]
    assert free[1] < 0
    w, change = nonnegative_weights(*_normal(C, target))
    assert np.all(w >= 0) and w[1] == 0.0
    assert change <= 0.0
    # the constrained optimum: no non-negative perturbation does better
    for d in np.eye(3) * 1e-3:
        trial = np.maximum(w + d, 0)
        assert np.sum((C @ trial - target) ** 2) >= np.sum((C @ w - target) ** 2) - 1e-12


def test_bad_normal_equations_raise_one_clear_error() -> None:
    with pytest.raises(CalibrationFitError, match="does not match"):
        nonnegative_weights(np.eye(2), np.ones(3))
    with pytest.raises(CalibrationFitError, match="not finite"):
        nonnegative_weights(np.eye(2), np.array([1.0, np.nan]))
