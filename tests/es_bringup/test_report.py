"""The main job's report on synthetic runs: summary.json schema, figures, Markdown."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from es_bringup.invariants import InvariantReport
from es_bringup.metrics import align_run, run_metrics
from es_bringup.report import ReportInputs, RunResult, write_report

RATE = 50.0


def synthetic_run(scenario: str, mode: str, slope: float, grid: tuple[int, int]) -> RunResult:
    """Output = (1 - slope (T - 46)) * set point, one step late, T stepped 40 -> 52 degC."""
    steps = 7 * 3 * int(RATE)
    t = np.arange(steps) / RATE
    sp = 50e-9 * (1.0 - np.cos(2 * np.pi * t))
    temp = 40.0 + 2.0 * np.floor(np.maximum(t - 1 / RATE, 0) / 3.0)
    gain = 1.0 - slope * (temp - 46.0)
    setpoint = np.broadcast_to(sp[:, None, None], (steps, *grid)).copy()
    temperature = np.broadcast_to(temp[:, None, None], (steps, *grid)).copy()
    displacement = np.zeros_like(setpoint)
    displacement[1:] = setpoint[:-1] * gain[1:, None, None]
    run = align_run(t, displacement, setpoint, t, temperature)
    metrics, slots = run_metrics(run, 1.0, skip_s=1.0)
    return RunResult(
        scenario, mode, Path(f"bags/{scenario}-{mode}"), metrics, slots, run,
        InvariantReport(), wall_s=1.0, sim_s=float(t[-1]),
    )  # fmt: skip


def test_report_writes_summary_figures_and_markdown(tmp_path: Path) -> None:
    runs = [
        synthetic_run("thesis_ac", "uncompensated", 0.03, (1, 1)),
        synthetic_run("thesis_ac", "inverse_hyperbolic", 0.003, (1, 1)),
        synthetic_run("dm_exposure", "uncompensated", 0.03, (3, 3)),
        synthetic_run("dm_exposure", "inverse_hyperbolic", 0.0, (3, 3)),
    ]
    runs[1].invariants.failures.append("/dm/command: 1 non-finite values")
    report = write_report(ReportInputs(runs, tmp_path / "bags", notes=["A note."]), tmp_path)

    doc = json.loads((tmp_path / "summary.json").read_text())
    assert set(doc) == {"scenarios", "bag"}
    assert doc["bag"] == str(tmp_path / "bags")
    assert set(doc["scenarios"]) == {"thesis_ac", "dm_exposure"}
    for modes in doc["scenarios"].values():
        assert set(modes) == {"uncompensated", "inverse_hyperbolic"}
        for figures in modes.values():
            assert set(figures) == {"variation_m", "reduction", "rms_error_m", "max_error_m"}
    ac = doc["scenarios"]["thesis_ac"]
    assert ac["uncompensated"]["reduction"] == 0.0
    assert ac["inverse_hyperbolic"]["reduction"] == pytest.approx(0.9, abs=1e-6)
    assert ac["uncompensated"]["variation_m"] == pytest.approx(18e-9, rel=1e-3)
    assert doc["scenarios"]["dm_exposure"]["inverse_hyperbolic"]["reduction"] == pytest.approx(1.0)

    text = report.read_text()
    assert "87.0 %" in text and "75.0 %" in text
    assert "FAILED" in text and "non-finite" in text
    assert "A note." in text
    pngs = sorted(p.name for p in (tmp_path / "figures").glob("*.png"))
    # the grid scenario gets an error map, the single actuator does not
    assert pngs == [
        "dm_exposure_error_map.png",
        "dm_exposure_error_vs_temperature.png",
        "dm_exposure_periods.png",
        "thesis_ac_error_vs_temperature.png",
        "thesis_ac_periods.png",
    ]
    for png in pngs:
        assert f"figures/{png}" in text
        assert (tmp_path / "figures" / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
