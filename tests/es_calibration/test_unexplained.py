"""What no candidate explains is stated in numbers a person can act on, and the tool exits 0.

The bags come from the hyperbolic law alone (law_bags.py) with structure added that no
candidate effect produces: a 1.0 nm vibration at 17.3 Hz, a 0.7 nm tone at 4.9 Hz
(= 2 x 1.1 Hz + 2.7 Hz, the command's tones) and a term proportional to dV/dt (a lead of the
displacement on the command, which no delay can model).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from es_calibration.calibrate import run
from es_calibration.search.unexplained import Drive
from es_calibration.verdict import WRITTEN

from . import law_bags as lb

VIBRATION = (17.3, 1.0e-9)  # frequency [Hz], amplitude [m]
DRIVE_TONE = (4.9, 0.7e-9)
RATE_COEFFICIENT = 2.0e-12  # [m per V/s]
LINE = re.compile(r"spectral line at ([\d.]+) Hz: amplitude ([\d.e+-]+) nm")
SLOPE = re.compile(r"slope ([+-][\d.e+-]+) nm per (\S+);")


def _calibrate(series: lb.Series, out: Path) -> dict[str, Any]:
    bag = lb.write(series, out / "bag")
    assert run([str(bag), "-o", str(out / "out"), "-q"]) in WRITTEN
    doc: dict[str, Any] = json.loads((out / "out" / "calibration.json").read_text())
    doc["report"] = (out / "out" / "report.md").read_text()
    return doc


@pytest.fixture(scope="module")
def structured(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    law = lb.law_run(60.0)
    t, z = law.topics["/dm/displacement"]
    rate = np.gradient(law.voltage, law.t, axis=0)
    extra = (
        VIBRATION[1] * np.sin(2 * np.pi * VIBRATION[0] * t)[:, None, None]
        + DRIVE_TONE[1] * np.sin(2 * np.pi * DRIVE_TONE[0] * t + 1.0)[:, None, None]
        + RATE_COEFFICIENT * rate
    )
    series = {**law.topics, "/dm/displacement": (t, z + extra)}
    return _calibrate(series, tmp_path_factory.mktemp("structured"))


def _line(doc: dict[str, Any], freq: float) -> tuple[float, float, str]:
    for note in doc["unexplained"]:
        found = LINE.match(note)
        if found and abs(float(found.group(1)) - freq) < 0.1:
            return float(found.group(1)), float(found.group(2)), note
    raise AssertionError(f"no line near {freq} Hz in {doc['unexplained']}")


def test_no_candidate_is_accepted_for_it(structured) -> None:
    assert structured["effects"] == []
    ratio = structured["heldout_rms_after_m"] / structured["noise_floor_m"]
    assert ratio > 3.0
    assert f"is {ratio:.2f} x the noise floor" in structured["unexplained"][0]


def test_vibration_line_is_reported_with_frequency_and_amplitude(structured) -> None:
    freq, amplitude, note = _line(structured, VIBRATION[0])
    assert freq == pytest.approx(VIBRATION[0], abs=0.05)
    assert amplitude == pytest.approx(VIBRATION[1] * 1e9, rel=0.15)
    assert "look for a vibration or pickup at 17.30 Hz" in note


def test_line_made_by_the_command_tones_is_attributed_to_the_drive(structured) -> None:
    freq, amplitude, note = _line(structured, DRIVE_TONE[0])
    assert freq == pytest.approx(DRIVE_TONE[0], abs=0.05)
    assert amplitude == pytest.approx(DRIVE_TONE[1] * 1e9, rel=0.15)
    assert "2 x 1.10 Hz +1 x 2.70 Hz" in note and "vibration" not in note


def test_rate_correlation_is_named_with_its_slope(structured) -> None:
    (note,) = [n for n in structured["unexplained"] if "correlates with dV/dt" in n]
    found = SLOPE.search(note)
    assert found is not None
    slope, unit = found.groups()
    assert unit == "V/s"
    assert float(slope) == pytest.approx(RATE_COEFFICIENT * 1e9, rel=0.2)
    # positive slope: the displacement runs ahead of the command, by slope / gain
    assert "leads the modelled response by" in note
    others = ("correlates with T ", "correlates with time")
    assert not any(o in n for o in others for n in structured["unexplained"])
    assert "Unexplained structure" in structured["report"] and note in structured["report"]


def test_clean_run_leaves_nothing_unexplained(tmp_path: Path) -> None:
    doc = _calibrate(lb.law_run(60.0, seed=2).topics, tmp_path)
    assert doc["effects"] == []
    assert doc["unexplained"] == []


def test_combinations_of_the_command_tones() -> None:
    drive = Drive(gain_m_per_v=1e-9, tones_hz=(1.1, 2.7), resolution_hz=0.05)
    assert drive.combination(2.7) == "1 x 2.70 Hz"
    assert drive.combination(1.6) == "-1 x 1.10 Hz +1 x 2.70 Hz"
    assert drive.combination(5.4) == "2 x 2.70 Hz"
    assert drive.combination(17.3) is None  # beyond order 4
    assert Drive(1e-9, (), 0.05).combination(2.7) is None
