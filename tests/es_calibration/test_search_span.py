"""The effect search's bounded span on long recordings (searchspan.py, issue 18)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from standgen.sweep import build_cases

from es_calibration.data.align import AlignedData, MeasuredData, align
from es_calibration.data.gaps import COMMAND_SETTLING_S
from es_calibration.data.searchspan import (
    SEARCH_BUDGET,
    SearchBudgetError,
    search_span,
    search_windows,
)
from es_calibration.pipeline import calibrate
from es_calibration.search.state import SCREEN_SIZE
from tests.es_calibration import law_bags as lb

from .measured_bags import read_measured_bags

GRID = (4, 4)  # within the screening block: the whole grid is searched, then refitted
EXPANSION_M_PER_DEGC = 0.4e-9


@pytest.fixture(scope="module")
def measured(tmp_path_factory: pytest.TempPathFactory) -> MeasuredData:
    run = lb.law_run(24.0, seed=7, shape=GRID)
    t, z = run.topics["/dm/displacement"]
    z = z + EXPANSION_M_PER_DEGC * (run.temperature - 40.0)
    series = {**run.topics, "/dm/displacement": (t, z)}
    return read_measured_bags([lb.write(series, tmp_path_factory.mktemp("span") / "bag")])


def _blocks(aligned: AlignedData, windows: list[tuple[int, int]]) -> list[int]:
    """Return the block of each window, checking that the window lies inside it."""
    found = []
    for a, b in windows:
        k = int(np.searchsorted(aligned.block_edges, aligned.t[a], side="right")) - 1
        assert aligned.t[b - 1] <= aligned.block_edges[k + 1]
        assert bool(aligned.train[a]) == (k % 2 == 0)
        found.append(k)
    return found


def test_windows_cover_the_run_one_per_block(measured: MeasuredData) -> None:
    aligned = align(measured)
    A = aligned.n_actuators
    blocks = aligned.block_edges.size - 1
    budget = int(0.8 * aligned.t.size) * A  # windows of 1.2 s: one in every block
    windows = search_windows(aligned, budget)
    assert _blocks(aligned, windows) == list(range(blocks))
    rows = sum(b - a for a, b in windows)
    assert 0.9 * budget // A <= rows <= budget // A
    # 4 s of samples: windows shorter than their 1 s lead-in would cost more commands than
    # samples, so two pairs (train + held out), at the run's start and end
    short = search_windows(aligned, int(4.0 * aligned.sample_rate) * A)
    assert _blocks(aligned, short) == [0, 1, blocks - 2, blocks - 1]
    budget = int(0.6 * aligned.t.size) * A  # 14.4 s of samples: 7 pairs of 8
    windows = search_windows(aligned, budget)
    chosen = _blocks(aligned, windows)
    assert len(chosen) == 14 and chosen[:2] == [0, 1] and chosen[-2:] == [blocks - 2, blocks - 1]
    rows = sum(b - a for a, b in windows)
    span = search_span(aligned, budget)
    assert span.t.size == rows and span.displacement.shape == (rows, A)
    assert span.train.any() and (~span.train).any()
    assert span.mean_temperature == aligned.mean_temperature
    assert span.command_period == aligned.command_period
    times = aligned.command_times
    for a, _ in windows:  # every window has the commands of its settling lead-in
        lead = times[(times >= aligned.t[a] - COMMAND_SETTLING_S) & (times <= aligned.t[a])]
        assert np.isin(lead, span.command_times).all()
    assert span.command_times.size < aligned.command_times.size


def test_a_record_within_the_budget_is_searched_whole(measured: MeasuredData) -> None:
    aligned = align(measured)
    assert search_span(aligned, aligned.t.size * aligned.n_actuators) is aligned
    assert search_windows(aligned, aligned.t.size * aligned.n_actuators) == []
    with pytest.raises(SearchBudgetError, match="positive"):
        search_span(aligned, 0)


def test_budget_gives_the_same_calibration(measured: MeasuredData) -> None:
    """Just over the budget: same effects, every parameter within its 1 sigma of the whole."""
    A = GRID[0] * GRID[1]
    samples = align(measured).t.size
    whole = calibrate(measured, ("thermal_expansion",))
    cut = calibrate(measured, ("thermal_expansion",), search_budget=int(0.8 * samples) * A)
    assert [e.name for e in cut.effects] == [e.name for e in whole.effects] == [
        "thermal_expansion"]
    a, b = whole.final.fit, cut.final.fit
    assert np.all(np.abs(a.glob - b.glob) <= np.sqrt(np.diag(a.cov_global)))
    assert np.all(np.abs(a.local - b.local) <= np.sqrt(np.einsum("app->ap", a.cov_local)))
    alpha = cut.effects[0].parameters["alpha_m_per_degc"]
    assert abs(alpha - whole.effects[0].parameters["alpha_m_per_degc"]) <= (
        whole.effects[0].uncertainties["alpha_m_per_degc"])
    assert cut.final.heldout_count == whole.final.heldout_count  # the final fit: whole record
    assert cut.aligned.t.size == whole.aligned.t.size
    # the report and calibration.json say what the search saw
    assert whole.search_span == ""
    assert "windows" in cut.search_span and "whole record" in cut.search_span


def test_identification_sweep_recordings_are_within_the_budget() -> None:
    """The sweep's cases (#14's figures) are searched whole: under the budget on the block."""
    for case in build_cases(quick=False):
        c = case.config
        block = min(c.rows, SCREEN_SIZE) * min(c.cols, SCREEN_SIZE)
        assert c.duration_s * c.rate_hz * block <= SEARCH_BUDGET, case.name


def test_cli_refuses_a_search_budget_below_one(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "es_calibration.calibrate", str(tmp_path / "none"), "-o",
           str(tmp_path / "out"), "--search-budget", "0"]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "calibrate: --tile, --search-budget and --workers must be at least 1"]
