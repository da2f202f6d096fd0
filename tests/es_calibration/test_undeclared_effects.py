"""End to end: plant-core bags with one undeclared effect each (and a clean one) -> calibrate.

Each bag is a 24 s characterisation run at 250 Hz (1 x 1, or 3 x 3 for the coupling), with
0.2 nm interferometer noise; the tool gets only the bag. It must name the effect, estimate
its parameter within the stated tolerance, cut the held-out error and bring it to within
1.2 x the measurement noise floor; on the clean bag it must add nothing.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from es_calibration.calibrate import run
from es_calibration.verdict import WRITTEN
from es_feedforward.param_file import read_params_file
from es_msgs_py.bag import write_array_bag

from . import calibration_bags as plantdata

Check = Callable[[dict[str, float], Any], None]


@dataclass(frozen=True)
class Case:
    rows: int
    settings: dict[str, float]
    check: Check


def _close(value: float, want: float, rel: float) -> None:
    assert abs(value - want) <= rel * abs(want), f"{value} not within {rel:.0%} of {want}"


def _hysteresis(p: dict[str, float], result: Any) -> None:
    # the tool reports the weight at the data's mean temperature; the plant's weight is at Tm+2
    mean_t = float(np.mean(result.temperature_raw))
    _close(p["weight"], 0.1 * np.exp(-(mean_t - 40.0) / 4.0), 0.15)
    _close(p["threshold_v"], 30.0, 0.15)


def _delay(p: dict[str, float], result: Any) -> None:
    # a zero-order-hold command resolves the delay to one command period
    assert abs(p["delay_s"] - 0.010) <= 1.0 / result.scenario.control_rate


def _expansion(p: dict[str, float], result: Any) -> None:
    _close(p["alpha_m_per_degc"], 0.4e-9, 0.1)
    _close(p["reference_temperature"], 40.0, 0.025)


def _drift(p: dict[str, float], result: Any) -> None:
    # the drift over 24 s (tau 300 s physical = 6 s) is only partly separable from the T law
    _close(p["fraction"], 0.03, 0.35)
    _close(p["tau_s"], 6.0, 0.5)


def _curvature(p: dict[str, float], result: Any) -> None:
    _close(p["m3"], 1.0e-18, 0.2)
    _close(p["k3"], 0.3e-9, 0.4)


def _nothing(p: dict[str, float], result: Any) -> None:
    pass


CASES: dict[str, Case] = {
    "clean": Case(1, {}, _nothing),
    # tau 100 s physical = 2 s at the test's time scale 0.02
    "sensor_lag": Case(1, {"tau_s": 100.0}, lambda p, r: _close(p["tau_s"], 2.0, 0.1)),
    "delay": Case(1, {"delay_s": 0.010}, _delay),
    "hysteresis": Case(1, {}, _hysteresis),
    "coupling": Case(3, {}, lambda p, r: _close(p["coefficient"], 0.05, 0.05)),
    "thermal_expansion": Case(1, {}, _expansion),
    "drift": Case(1, {}, _drift),
    "temperature_curvature": Case(1, {}, _curvature),
}


@pytest.fixture(scope="module", params=list(CASES))
def calibrated(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):
    name = request.param
    case = CASES[name]
    effects = {} if name == "clean" else {name: {"enabled": True, **case.settings}}
    result = plantdata.run(plantdata.scenario(case.rows, case.rows, effects=effects))
    tmp = tmp_path_factory.mktemp(name)
    bag = plantdata.write_bag(result, tmp / "bag")
    assert run([str(bag), "-o", str(tmp / "out"), "-q"]) in WRITTEN
    doc = json.loads((tmp / "out" / "calibration.json").read_text())
    return name, case, result, doc, tmp / "out"


def test_names_the_effect_and_estimates_it(calibrated) -> None:
    name, case, result, doc, _ = calibrated
    names = [e["name"] for e in doc["effects"]]
    if name == "clean":
        assert names == []
        return
    assert names == [name]
    case.check(doc["effects"][0]["parameters"], result)


def test_cuts_heldout_error_to_the_noise_floor(calibrated) -> None:
    name, _, result, doc, _ = calibrated
    noise = plantdata.truth_rms(result)
    floor = doc["noise_floor_m"]
    assert floor == pytest.approx(noise, rel=0.15)  # the floor estimate is honest
    assert doc["heldout_rms_after_m"] <= 1.2 * floor
    if name != "clean":
        effect = doc["effects"][0]
        assert effect["rms_after_m"] < 0.8 * effect["rms_before_m"]
        assert doc["heldout_rms_after_m"] < doc["heldout_rms_before_m"]
        assert doc["unexplained"] == []


def test_parameter_file_loads_with_the_compensation(calibrated) -> None:
    name, case, result, doc, out = calibrated
    config = read_params_file(out / "feedforward_params.yaml")
    assert config.shape == (case.rows, case.rows)
    m2 = np.broadcast_to(np.asarray(config.params.m2), config.shape)
    np.testing.assert_allclose(m2.ravel(), doc["law"]["m2"])
    np.testing.assert_allclose(m2, result.true_params.m2, rtol=0.01)
    comp = config.compensation
    params = doc["effects"][0]["parameters"] if doc["effects"] else {}
    expected = {
        "clean": ("coupling", 0.0),
        "sensor_lag": ("temperature_lead_s", params.get("tau_s")),
        "delay": ("delay_s", params.get("delay_s")),
        "hysteresis": ("hysteresis_weight", params.get("weight")),
        "coupling": ("coupling", params.get("coefficient")),
        "thermal_expansion": ("thermal_expansion", params.get("alpha_m_per_degc")),
        "drift": ("drift_fraction", params.get("fraction")),
    }
    if name == "temperature_curvature":
        assert np.allclose(np.asarray(config.params.m3), doc["law"]["m3"])
    else:
        field, value = expected[name]
        assert getattr(comp, field) == pytest.approx(value)


def test_report_shows_every_step(calibrated) -> None:
    name, _, _, _, out = calibrated
    report = (out / "report.md").read_text()
    for heading in ("## a.", "## b.", "## c.", "## d.", "## e."):
        assert heading in report
    for png in (
        "residual_time.png",
        "residual_vs_inputs.png",
        "residual_spectrum.png",
        "residual_correlation.png",
    ):
        assert (out / png).stat().st_size > 1000
    if name != "clean":
        assert f"added **{name}**" in report


def test_structure_no_candidate_explains_is_reported_not_attributed(tmp_path: Path) -> None:
    # a 7 Hz vibration on the interferometer reading: no candidate effect produces it
    result = plantdata.run(plantdata.scenario(1, 1))
    dt = 1.0 / result.scenario.control_rate
    line = 1.0e-9 * np.sin(2 * np.pi * 7.0 * (result.time + dt))[:, None, None]
    bag = tmp_path / "bag"
    write_array_bag(
        bag,
        {
            "/dm/command": (result.time, result.command),
            "/dm/displacement": (result.time + dt, result.displacement_measured + line),
            "/dm/temperature/raw": (result.sensor_time, result.temperature_raw),
        },
    )
    assert run([str(bag), "-o", str(tmp_path / "out"), "-q"]) in WRITTEN
    doc = json.loads((tmp_path / "out" / "calibration.json").read_text())
    assert doc["effects"] == []
    lines = [re.match(r"spectral line at ([0-9.]+) Hz", note) for note in doc["unexplained"]]
    assert any(m is not None and abs(float(m.group(1)) - 7.0) < 0.05 for m in lines)
    assert any("noise floor" in note for note in doc["unexplained"])
