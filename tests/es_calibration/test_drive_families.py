"""Calibration models of self-heating and frequency dispersion, on independent stand data.

The bags come from testing/standgen (a second implementation of the physics, sharing no code
with the calibration): the family present must be the one accepted, with its parameters
within a few sigma of the stand's truth, and its compensation values usable by the
feedforward; a clean recording must accept nothing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from standgen import StandConfig, simulate, write_bag
from standgen.effects import Effects, FrequencyDispersion, SelfHeating

from es_calibration.output.schema import compensation
from es_calibration.pipeline import Calibration, calibrate

from .measured_bags import read_measured_bags

#: Sigmas within which a fitted parameter must lie of the truth.
SIGMAS = 5.0


def _calibrate(tmp_path: Path, effects: Effects, **conditions: object) -> Calibration:
    config = StandConfig(
        **{
            "rows": 1,
            "cols": 1,
            "rate_hz": 500.0,
            "duration_s": 30.0,
            "effects": effects,
            "drop_fraction": 0.02,
            "seed": 5,
            **conditions,
        }  # type: ignore[arg-type]
    )
    write_bag(simulate(config), tmp_path / "bag", "mcap")
    return calibrate(read_measured_bags([tmp_path / "bag"]))


def _near(cal: Calibration, name: str, truth: dict[str, float]) -> None:
    (effect,) = cal.effects
    assert effect.name == name
    for key, value in truth.items():
        fitted, sigma = effect.parameters[key], effect.uncertainties[key]
        assert 0.0 < sigma < 0.2 * abs(value), (key, fitted, sigma)
        assert abs(fitted - value) < SIGMAS * sigma, (key, fitted, value, sigma)


@pytest.mark.slow
def test_self_heating_is_found_on_a_grid_with_its_gain_and_time_constant(tmp_path: Path) -> None:
    gain, tau = 1.5e-5, 1.2
    cal = _calibrate(
        tmp_path,
        Effects(self_heating=SelfHeating(gain, tau)),
        rows=2,
        cols=2,
        rate_hz=250.0,
        temperature_kind="raw",
    )
    _near(cal, "self_heating", {"gain": gain, "tau_s": tau})
    comp, notes = compensation(cal)
    assert not notes
    assert comp.self_heating_gain == cal.effects[0].parameters["gain"]
    assert comp.self_heating_tau_s == cal.effects[0].parameters["tau_s"]
    assert cal.final.heldout_rms < 1.2 * cal.noise_floor_m


@pytest.mark.slow
def test_frequency_dispersion_is_found_with_its_fraction_and_corner(tmp_path: Path) -> None:
    strength, corner = 0.08, 6.0
    cal = _calibrate(tmp_path, Effects(frequency_dispersion=FrequencyDispersion(strength, corner)))
    _near(cal, "frequency_dispersion", {"fraction": strength, "corner_hz": corner})
    comp, notes = compensation(cal)
    assert not notes
    assert comp.dispersion_fraction == cal.effects[0].parameters["fraction"]
    assert comp.dispersion_corner_hz == cal.effects[0].parameters["corner_hz"]
    assert cal.final.heldout_rms < 1.2 * cal.noise_floor_m


@pytest.mark.slow
def test_a_clean_stand_accepts_neither_family(tmp_path: Path) -> None:
    cal = _calibrate(tmp_path, Effects(), rows=2, cols=2, rate_hz=250.0)
    assert cal.effects == []
    tried = {s.name for r in cal.rounds for s in r.scores}
    assert {"self_heating", "frequency_dispersion"} <= tried
    assert np.isfinite(cal.final.heldout_rms)
