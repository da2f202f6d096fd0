"""The halves check's sign rule: a whole-record value both halves reverse is a stand-in."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from es_calibration.search import halves


@pytest.fixture
def whole_fit(monkeypatch: pytest.MonkeyPatch) -> dict[str, dict[str, float]]:
    """Stand the whole record's fit in: ``fit["values"]`` and ``fit["sigma"]``, set by a test."""
    fit: dict[str, dict[str, float]] = {"values": {}, "sigma": {}}
    effect = SimpleNamespace(reported=lambda f: dict(fit["values"]),
                             uncertainties=lambda f: dict(fit["sigma"]))
    monkeypatch.setattr(halves, "get", lambda name: effect)
    monkeypatch.setattr(halves, "fitted_effect", lambda state, eff, aligned: None)
    return fit


def _why(halves_values: list[dict[str, float]]) -> str | None:
    ws = SimpleNamespace(aligned=None)
    return halves._between_halves(None, halves_values, "temperature_curvature", ws)  # type: ignore[arg-type]


def test_a_sign_both_halves_reverse_is_named_with_the_three_values(
    whole_fit: dict[str, dict[str, float]],
) -> None:
    # the independent stand's periodic metrology error taken by a temperature curvature
    whole_fit["values"] = {"m3": 2.19e-19, "k3": 2.57e-10}
    whole_fit["sigma"] = {"m3": 0.95e-19, "k3": 1.24e-10}
    why = _why([{"m3": -1.22e-19, "k3": -2.85e-10}, {"m3": -3.59e-20, "k3": 1.66e-10}])
    assert why == ("m3 2.19e-19 on the whole record, of the other sign on both halves "
                   "(-1.22e-19, -3.59e-20): it follows the difference between them")


def test_a_value_one_half_shares_or_the_whole_does_not_determine_holds(
    whole_fit: dict[str, dict[str, float]],
) -> None:
    whole_fit["values"] = {"m3": 2.19e-19}
    whole_fit["sigma"] = {"m3": 0.95e-19}
    assert _why([{"m3": -1.22e-19}, {"m3": 0.5e-19}]) is None
    whole_fit["sigma"] = {"m3": 1.5e-19}  # 1.5 sigma from 0: its sign says nothing
    assert _why([{"m3": -1.22e-19}, {"m3": -0.5e-19}]) is None
    # a value without an uncertainty (a scanned threshold) is not compared
    whole_fit["values"], whole_fit["sigma"] = {"threshold_v": 5.0}, {}
    assert _why([{"threshold_v": -5.0}, {"threshold_v": -5.0}]) is None
