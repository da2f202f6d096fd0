"""Command edges the command samples cannot resolve: found, their samples left out, reported.

The rule (edges.py) on synthetic commands with known steps, on smooth commands (nothing
goes), end to end through the tool (calibration.json and the report say what went), and on
an independent test-stand case (testing/standgen) whose delay fit it rescues.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from standgen import simulate
from standgen.sweep import build_cases

from es_calibration.calibrate import run
from es_calibration.data.align import EDGE_DROPS, MeasuredData, align
from es_calibration.data.delayrange import shift_span
from es_calibration.data.edges import EDGE_MARGIN_PERIODS, exclude_edges, find_edges

from . import law_bags as lb
from .stand_data import measured

RATE = 250.0
T = 1.0 / RATE


def _tones(t: np.ndarray) -> np.ndarray:
    """Two actuators of smooth drive: slow and fast tones (the fastest 25 Hz, 10 samples)."""
    return np.stack(
        [
            120.0 + 90.0 * np.sin(2 * np.pi * 1.3 * t) + 40.0 * np.sin(2 * np.pi * 25.0 * t + 1),
            60.0 * np.sin(2 * np.pi * 0.4 * t) + 8.0 * np.sin(2 * np.pi * 7.0 * t),
        ],
        axis=1,
    )


def test_a_step_is_an_edge_and_takes_the_samples_that_could_read_it() -> None:
    t = np.arange(0.0, 10.0, T)
    command = _tones(t)
    command[t > 5.0012, 1] += 30.0  # a step inside the interval from 5.000 s to 5.004 s
    edges = find_edges(t, command)
    k = int(np.searchsorted(t, 5.0))  # the interval's index
    assert k in edges
    assert set(edges) <= {k - 1, k, k + 1}  # the step alone (its neighbours move by half)
    samples = t + 0.5 * T  # a displacement half a period after each command
    out, account = exclude_edges(samples, t, command)
    lowest, highest = shift_span(T)
    first = t[edges[0]] - (1.0 + EDGE_MARGIN_PERIODS - lowest) * T
    last = t[edges[-1] + 1] + (1.0 + EDGE_MARGIN_PERIODS + highest) * T
    eps = 1e-9  # stamps on a span's end may round either way
    assert out[(samples > first + eps) & (samples < last - eps)].all()
    assert not out[(samples < first - eps) | (samples > last + eps)].any()
    # every sample whose input at any delay searched (up to 0.1 s here) could read the step
    assert last - t[k + 1] >= 0.1 and t[k] - first >= T
    assert account.edges == edges.size and account.excluded_samples == int(out.sum())
    assert account.example_times_s[0] == pytest.approx(t[edges[0]])
    assert account.fraction == pytest.approx(out.mean())


def test_smooth_commands_lose_nothing_even_with_dropped_messages() -> None:
    t = np.arange(0.0, 60.0, T)
    keep = np.random.default_rng(3).random(t.size) >= 0.02  # 2 % of the messages dropped
    out, account = exclude_edges(t[keep] + 0.5 * T, t[keep], _tones(t[keep]))
    assert account.edges == 0 and not out.any()
    # a ramp and a constant are smooth too; round-off is no edge
    flat = np.stack([np.linspace(0.0, 300.0, t.size), np.full(t.size, 50.0)], axis=1)
    flat[:, 1] += 1e-9 * np.random.default_rng(4).standard_normal(t.size)
    assert find_edges(t, flat).size == 0


def test_an_edge_next_to_a_command_hole_is_left_to_the_gap() -> None:
    t = np.arange(0.0, 10.0, T)
    command = _tones(t)
    hole = (t > 4.0) & (t < 4.1)
    command[t >= 4.1] += 50.0  # the command moved while no message came
    assert find_edges(t[~hole], command[~hole]).size == 0


def test_calibration_json_and_report_carry_the_edges(tmp_path: Path) -> None:
    law = lb.law_run(duration=16.0, shape=(1, 2), steps=(5.0, 11.0))
    bag = lb.write(law.topics, tmp_path / "bag")
    assert run([str(bag), "-o", str(tmp_path / "out"), "-q"]) == 0
    doc = json.loads((tmp_path / "out" / "calibration.json").read_text())
    edges = doc["data"]["command_edges"]
    # each step is an edge (its neighbour intervals may count too), nothing else is
    assert 2 <= edges["edges"] <= 6
    start = doc["data"]["start_time_s"]
    found = np.array(edges["example_times_s"]) - start
    assert np.all(np.min(np.abs(found[:, None] - np.array([5.0, 11.0])[None]), axis=1) < 2.5 * T)
    assert edges["excluded_samples"] == doc["data"]["dropped"][EDGE_DROPS]
    # two spans of (2.95 + 1 + 25 + 2.5 + 2) periods and the step's one to three intervals
    per_edge = edges["excluded_before_s"] + edges["excluded_after_s"]
    assert 2 * (per_edge + T) * RATE - 2 <= edges["excluded_samples"]
    assert edges["excluded_samples"] <= 2 * (per_edge + 3 * T) * RATE + 2
    assert edges["excluded_fraction"] == pytest.approx(
        edges["excluded_samples"] / (doc["data"]["samples"] + edges["excluded_samples"])
    )
    report = (tmp_path / "out" / "report.md").read_text()
    assert f"{edges['excluded_samples']} displacement samples" in report
    assert "cannot resolve" in report


def _delay_case(seconds: float) -> tuple[MeasuredData, float]:
    """Return the sweep's delay+drift case (2 x 2, 250 Hz), shortened, and its true noise."""
    case = next(c for c in build_cases() if c.name == "delay+drift")
    config = replace(case.config, duration_s=seconds, temperature_kind="grid")
    return measured(simulate(config)), config.noise_rms_m


def test_standgen_delay_case_is_rescued_by_the_edge_rule() -> None:
    # sweep case delay+drift: the stand's program joins segments with 2 ms edges that 250 Hz
    # command samples cannot resolve; with a fractional delay the samples reading them were
    # 15-25x the noise and the held-out RMS after the search 3.3x the noise
    from es_calibration.pipeline import _search
    from es_calibration.search.state import choose_stamp_convention

    data, noise = _delay_case(30.0)  # the old rule-less search: 2.1x the noise
    aligned = choose_stamp_convention(align(data))
    account = aligned.command_edges
    assert account is not None and account.edges > 0
    assert 0.0 < account.fraction < 0.2
    _, _, _, final, _, _ = _search(aligned, aligned.grid, ("delay", "drift"))
    assert set(final.model.effects) == {"delay", "drift"}
    assert final.heldout_rms < 1.2 * noise
