"""The rule two fits of one effect must agree by, and the free per-actuator offset."""

from __future__ import annotations

import numpy as np
import pytest

from es_calibration.model.composite import Evaluation
from es_calibration.search.agreement import NotANumberError, disagreement
from es_calibration.search.offsets import _with_offsets


def test_values_within_their_uncertainty_or_half_their_size_agree() -> None:
    sigma = {"c": 0.001}
    assert disagreement([{"c": 0.030}, {"c": 0.031}], [sigma, sigma]) is None
    # far apart in sigmas but within half the larger magnitude: agrees
    assert disagreement([{"c": 0.030}, {"c": 0.020}], [sigma, sigma]) is None


def test_a_collapsing_value_is_named_with_both_values() -> None:
    moved = disagreement([{"c": 0.0303}, {"c": 0.0004}], [{"c": 2e-4}, {"c": 2e-4}])
    assert moved is not None
    key, a, b, combined = moved
    assert (key, a, b) == ("c", 0.0303, 0.0004)
    assert combined == pytest.approx(np.hypot(2e-4, 2e-4))


def test_a_parameter_without_an_uncertainty_is_not_compared() -> None:
    assert disagreement([{"c": 1.0, "d": 5.0}, {"c": 1.0, "d": -5.0}],
                        [{"c": 0.1}, {"c": 0.1}]) is None


def test_a_value_that_is_not_a_number_is_refused() -> None:
    with pytest.raises(NotANumberError):
        disagreement([{"c": np.nan}, {"c": 1.0}], [{"c": 0.1}, {"c": 0.1}])


def test_the_free_offset_centres_prediction_and_jacobians_over_valid_samples() -> None:
    rng = np.random.default_rng(0)
    prediction = rng.standard_normal((3, 50)) + np.array([[5.0], [-2.0], [0.0]])
    jac_local = rng.standard_normal((3, 50, 2))
    jac_global = np.ones((3, 50, 1))  # a constant column: nothing left once centred
    valid = rng.random((3, 50)) > 0.2
    valid[2, :] = False
    out = _with_offsets(Evaluation(prediction, jac_local, jac_global), valid)
    for a in range(2):
        assert abs(out.prediction[a, valid[a]].mean()) < 1e-12
        assert np.abs(out.jac_local[a, valid[a]].mean(axis=0)).max() < 1e-12
    assert np.abs(out.jac_global[:2]).max() < 1e-12
    # an actuator with no valid sample keeps its values (nothing to take a mean over)
    np.testing.assert_array_equal(out.prediction[2], prediction[2])


def test_a_parameter_not_a_number_with_offsets_refuses_the_candidate_with_a_reason(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the refit with free offsets gives NaN for a parameter: a reason, not a NotANumberError
    # out of the effect search (before 8118d5c it escaped; halves.py always caught it)
    from types import SimpleNamespace

    from es_calibration.search import offsets

    effect = SimpleNamespace(reported=lambda fit: fit, uncertainties=lambda fit: {"c": 1e-4})
    monkeypatch.setattr(offsets, "get", lambda name: effect)
    monkeypatch.setattr(offsets, "refit_with_offsets", lambda state, train: float("nan"))
    monkeypatch.setattr(offsets, "fitted_effect", lambda state, eff, aligned: {"c": state})
    why = offsets.offset_stand_in(0.03, "coupling", None, None)  # type: ignore[arg-type]
    assert why == "c not a number once each actuator may carry a constant offset"
