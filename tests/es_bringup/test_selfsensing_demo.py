"""The self-sensing section's files and scoring (pure parts of the demo section)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from es_bringup.selfsensing_demo import (
    case_figures,
    case_scenarios,
    sample_clock_copy,
    section_markdown,
    stand_scenario,
)
from es_bringup.selfsensing_study import CASES
from es_msgs_py.bag import read_bag, write_array_bag
from es_sim_plant.scenario import load_scenario, resolve_scenario


def test_case_scenarios_share_the_mirror_and_differ_in_sensors(tmp_path: Path) -> None:
    paths = case_scenarios(resolve_scenario("dm_exposure"), tmp_path)
    assert set(paths) == set(CASES)
    few = load_scenario(str(paths["ntc"]))
    every = load_scenario(str(paths["sensor_per_actuator"]))
    assert paths["ntc"] == paths["ntc_selfsensing"]
    assert few.sensors.positions is not None and len(few.sensors.positions) == 4
    assert every.sensors.positions is None
    assert few.resonance.enabled and every.resonance.enabled
    shipped = load_scenario("dm_exposure")
    assert (few.seed, few.shape) == (shipped.seed, shipped.shape)
    assert few.illumination == shipped.illumination


def test_stand_scenario_switches_the_sweeps_on(tmp_path: Path) -> None:
    source = tmp_path / "stand.yaml"
    source.write_text(resolve_scenario("characterisation").read_text())
    stand = load_scenario(str(stand_scenario(source, tmp_path)))
    assert stand.resonance.enabled and stand.excitation is not None


def test_sample_clock_copy_stamps_sweeps_with_their_sensor_samples(tmp_path: Path) -> None:
    sc = load_scenario("characterisation")
    every = round(sc.control_rate / sc.sensor_rate)
    steps = 3 * every
    stamps = np.zeros(steps)  # a lagging recorder: every stamp alike
    write_array_bag(
        tmp_path / "stand",
        {
            "/dm/command": (stamps, np.ones((steps, 12, 12))),
            "/dm/resonance": (stamps[:3], np.full((3, 12, 12), 1e6)),
            "/dm/temperature/raw": (stamps[:3], np.full((3, 144), 40.0)),
        },
    )
    copy = read_bag(sample_clock_copy(tmp_path / "stand", tmp_path / "daq", "characterisation"))
    np.testing.assert_allclose(copy["/dm/resonance"].times, np.arange(3) * every / sc.control_rate)
    np.testing.assert_allclose(copy["/dm/command"].times, np.arange(steps) / sc.control_rate)


def test_scores_and_section_text() -> None:
    error = np.zeros((20, 2, 2))
    error[:, 0, 1] = 0.1
    error[0] = 5.0  # start-up, not scored
    figures = case_figures("ntc", error, 2e-10)
    assert figures.worst == pytest.approx(0.1) and figures.max_error == pytest.approx(0.1)
    assert figures.rms == pytest.approx(0.05)
    cases = {
        name: case_figures(name, error * scale, 2e-10)
        for name, scale in zip(CASES, (1.0, 0.1, 0.5), strict=True)
    }
    text = section_markdown(cases, "figures/x.png", {"resonance.noise_hz": 12.0}, {})
    assert "10.0x lower RMS error" in text and "![self-sensing" in text
