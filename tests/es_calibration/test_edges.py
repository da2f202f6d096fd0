"""Command edges the command samples cannot resolve: found, their pairs left out, reported.

The rule (edges.py) on synthetic commands with known steps, on smooth commands (nothing
goes), per actuator (an edge takes only its own actuator's samples, and once the delay is
known only what that delay needs), end to end through the tool (calibration.json and the
report say what went), on an independent test-stand case (testing/standgen) whose delay fit
it rescues, and on an independently driven 8 x 8 stand recording, which keeps >= 90 %.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from standgen import StandConfig, draw_effects, simulate
from standgen.sweep import build_cases

from es_calibration.calibrate import run
from es_calibration.data.align import MeasuredData, align
from es_calibration.data.delayrange import shift_span
from es_calibration.data.edge_loop import departure_rows
from es_calibration.data.edges import (
    EDGE_MARGIN_PERIODS,
    REACH_PERIODS,
    EdgeMask,
    EdgeStream,
    _interval_geometry,
    account,
    departures,
    edge_mask,
    edge_pairs,
    find_edges,
)
from es_calibration.data.recording import MemoryRecording
from es_calibration.output.schema import calibration_document
from es_calibration.pipeline import _with_delay, calibrate
from es_calibration.verdict import WRITTEN
from es_feedforward.kernels import KERNELS_ENV

from . import law_bags as lb
from .independent_drive import simulate_independent
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
    mask = edge_mask(t, command)
    out = mask.excluded(samples, np.arange(2, dtype=np.intp))
    assert not out[0].any()  # the step is actuator 1's: actuator 0 keeps every sample
    lowest, highest = shift_span(T)
    first = t[edges[0]] - (1.0 + EDGE_MARGIN_PERIODS - lowest) * T
    last = t[edges[-1] + 1] + (1.0 + EDGE_MARGIN_PERIODS + highest) * T
    eps = 1e-9  # stamps on a span's end may round either way
    assert out[1, (samples > first + eps) & (samples < last - eps)].all()
    assert not out[1, (samples < first - eps) | (samples > last + eps)].any()
    # every sample whose input at any delay searched (up to 0.1 s here) could read the step
    assert last - t[k + 1] >= 0.1 and t[k] - first >= T
    found = account(mask, samples, 2)
    assert found.edges == edges.size and found.excluded_pairs == int(out.sum())
    assert found.per_actuator_edges[0] == 0 and found.per_actuator_excluded[0] == 0
    assert found.example_times_s[0] == pytest.approx(t[edges[0]])
    assert found.fraction == pytest.approx(out.mean())
    # once the delay is known (here 3.4 periods) the step takes only what that delay reads
    delay = 3.4 * T
    known = mask.with_delay(T, delay).excluded(samples, np.arange(2, dtype=np.intp))
    reach = (REACH_PERIODS + EDGE_MARGIN_PERIODS) * T
    lo, hi = t[edges[0]] + delay - reach, t[edges[-1] + 1] + delay + reach
    assert known[1, (samples > lo + eps) & (samples < hi - eps)].all()
    assert not known[1, (samples < lo - eps) | (samples > hi + eps)].any()
    assert known[1].sum() < 0.3 * out[1].sum()


def test_an_actuator_never_examined_takes_every_examined_edge() -> None:
    t = np.arange(0.0, 4.0, T)
    command = _tones(t)
    command[t > 2.0012, 1] += 30.0
    mask = edge_mask(t, command).renumbered(np.array([5, 9], dtype=np.intp))
    out = mask.excluded(t + 0.5 * T, np.array([5, 9, 7], dtype=np.intp))
    assert not out[0].any() and out[1].any()
    assert np.array_equal(out[2], out[1])  # actuator 7's commands were never looked at


def test_smooth_commands_lose_nothing_even_with_dropped_messages() -> None:
    t = np.arange(0.0, 60.0, T)
    keep = np.random.default_rng(3).random(t.size) >= 0.02  # 2 % of the messages dropped
    interval, _ = edge_pairs(t[keep], _tones(t[keep]))
    assert interval.size == 0
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
    assert run([str(bag), "-o", str(tmp_path / "out"), "-q"]) in WRITTEN
    doc = json.loads((tmp_path / "out" / "calibration.json").read_text())
    edges = doc["data"]["command_edges"]
    # each step is an edge (its neighbour intervals may count too), nothing else is
    assert 2 <= edges["edges"] <= 6
    start = doc["data"]["start_time_s"]
    found = np.array(edges["example_times_s"]) - start
    assert np.all(np.min(np.abs(found[:, None] - np.array([5.0, 11.0])[None]), axis=1) < 2.5 * T)
    # the steps drive both actuators: each has its own edges and loses its own pairs
    per = edges["per_actuator"]
    assert len(per["edges"]) == 2 and min(per["edges"]) >= 2
    assert sum(per["excluded_samples"]) == edges["excluded_pairs"]
    # at the delay found, two spans of (2 x (2 + 1) + 1 to 3) periods per actuator
    per_edge = edges["excluded_before_s"] + edges["excluded_after_s"]
    assert per_edge == pytest.approx(2 * (REACH_PERIODS + EDGE_MARGIN_PERIODS) * T)
    for n in per["excluded_samples"]:
        assert 2 * (per_edge + T) * RATE - 2 <= n <= 2 * (per_edge + 3 * T) * RATE + 2
    assert edges["excluded_fraction"] == pytest.approx(
        edges["excluded_pairs"] / (2 * doc["data"]["samples"])
    )
    assert doc["health"]["kept_fraction"] > 0.95
    report = (tmp_path / "out" / "report.md").read_text()
    assert f"{edges['excluded_pairs']} (sample, actuator) pairs" in report
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
    # the standgen program switches every actuator at once: each has edges of its own
    assert min(account.per_actuator_edges) > 0
    _, _, _, final, _, _ = _search(aligned, aligned.grid, ("delay", "drift"))
    assert set(final.model.effects) == {"delay", "drift"}
    assert final.heldout_rms < 1.2 * noise


def test_independently_driven_8x8_keeps_its_samples() -> None:
    # each actuator has its own program (its own segment instants): with one edge rule for
    # the whole grid this recording kept nothing (every sample read some actuator's edge);
    # per actuator the delay search's window keeps ~88 %, the known delay's >= 90 %
    effects = draw_effects(["delay"], np.random.default_rng(3), rate_hz=RATE, duration_s=30.0,
                           shape=(8, 8))
    config = StandConfig(rows=8, cols=8, rate_hz=RATE, duration_s=30.0, effects=effects,
                         seed=3, temperature_kind="grid")
    aligned = align(measured(simulate_independent(config)))
    mask = aligned.edge_mask
    assert mask.actuator.size > 64 * 20  # ~20 segment joins per actuator, each an edge
    whole_grid_rule = replace(mask, examined=np.zeros(0, np.intp))  # any edge takes all
    old = 1.0 - whole_grid_rule.excluded(aligned.t, np.arange(1, dtype=np.intp)).mean()
    assert old < 0.05
    assert aligned.kept_fraction() > 0.8
    assert effects.delay is not None
    known = _with_delay(aligned, effects.delay.delay_s)
    assert known.kept_fraction() >= 0.9
    assert known.command_edges is not None
    assert known.command_edges.fraction < 0.06


@pytest.mark.parametrize("backend", ["numpy", "fused"])
def test_edges_found_a_chunk_at_a_time_are_those_of_the_whole_record(
    monkeypatch: pytest.MonkeyPatch, backend: str
) -> None:
    # the grid-wide refit streams the command (recording.gather): the pairs must not depend
    # on where the chunks begin and end, nor on gaps and repeated stamps inside them, nor
    # on the kernels (the compiled departures are numpy's to the bit)
    rng = np.random.default_rng(5)
    for trial in range(20):
        n, width = int(rng.integers(20, 500)), int(rng.integers(1, 30))
        times = np.arange(n, dtype=np.float64) * T
        if trial % 3 == 0:
            times[n // 2:] += 20 * T  # a gap
        if trial % 4 == 0:
            times[10] = times[9]  # a repeated stamp
        command = np.cumsum(rng.normal(0.0, 0.01, (n, width)), axis=0) + np.sin(
            0.05 * np.arange(n)[:, None] + rng.uniform(0, 6, width))
        for row, actuator in zip(rng.integers(0, n, 2 * width), rng.integers(0, width, 2 * width),
                                 strict=True):
            command[row:, actuator] += rng.normal(0.0, 2.0)  # steps at their own instants
        monkeypatch.setenv(KERNELS_ENV, "numpy")
        whole = edge_pairs(times, command)
        numpy_departures = departures(times, command)
        monkeypatch.setenv(KERNELS_ENV, backend)
        stream = EdgeStream(times, width)
        start = 0
        while start < n:
            size = int(rng.integers(1, 60))
            stream.feed(command[start : start + size])
            start += size
        assert whole[0].size > 0
        if backend == "fused":
            compiled = np.empty_like(numpy_departures)
            length, w, usable = _interval_geometry(times, float(np.median(np.diff(times))))
            departure_rows(command, 0, length, w, usable, float(np.median(np.diff(times))),
                           compiled)
            np.testing.assert_array_equal(compiled, numpy_departures)
        for got, want in zip(stream.pairs(), whole, strict=True):
            np.testing.assert_array_equal(got, want)


def test_independently_driven_grid_beyond_the_block_keeps_its_samples() -> None:
    # 10 x 10: the actuators outside the 8 x 8 screening block are refitted from the
    # streamed gather; they once took every block actuator's edges (none of their own
    # were looked at), now each takes its own, found in the same pass
    effects = draw_effects(["delay"], np.random.default_rng(4), rate_hz=RATE, duration_s=30.0,
                           shape=(10, 10))
    config = StandConfig(rows=10, cols=10, rate_hz=RATE, duration_s=30.0, effects=effects,
                         seed=4, temperature_kind="grid")
    data = measured(simulate_independent(config))
    cal = calibrate(MemoryRecording(data), ("delay",))
    edges = cal.grid_edges
    assert edges is not None and cal.grid_kept_fraction is not None
    assert edges.actuators == 100 and min(edges.per_actuator_edges) > 10
    assert cal.grid_kept_fraction >= 0.9
    # the whole grid's own edges, as align finds them with the whole grid in memory
    whole = align(data).edge_mask
    assert edges.pairs == whole.actuator.size
    # the block's edges on every other actuator (the old rule) would have kept little
    block_rule = replace(cal.aligned.edge_mask.renumbered(np.arange(64, dtype=np.intp)),
                         examined=np.arange(64, dtype=np.intp))
    outside = np.array([99], dtype=np.intp)
    assert block_rule.excluded(cal.aligned.t, outside).mean() > 0.3
    doc = calibration_document(cal)
    assert doc["data"]["grid_command_edges"]["per_actuator"]["edges"] == list(
        edges.per_actuator_edges)
    assert doc["health"]["grid_kept_fraction"] == cal.grid_kept_fraction


def test_the_excluded_counts_are_the_sums_of_the_excluded_pairs() -> None:
    # account() counts a 64 x 64 grid's own edges without a (actuators, samples) array, and
    # a tile finds its pairs by search when they are sorted by actuator
    rng = np.random.default_rng(2)
    for trial in range(40):
        pairs, width, n = (int(v) for v in rng.integers((0, 1, 1), (200, 30, 400)))
        t = np.sort(rng.uniform(0.0, 10.0, n))
        start = rng.uniform(-1.0, 11.0, pairs)
        examined = np.sort(rng.choice(width, max(1, width // 2), replace=False))
        mask = EdgeMask(start, start + rng.uniform(0.0, 0.1, pairs),
                        rng.integers(0, width, pairs).astype(np.intp),
                        float(rng.uniform(0.0, 0.5)), float(rng.uniform(0.0, 0.5)),
                        examined=examined.astype(np.intp) if trial % 2 else None)
        actuators = np.sort(rng.choice(width + 3, int(rng.integers(1, width + 3)),
                                       replace=False)).astype(np.intp)
        np.testing.assert_array_equal(mask.excluded_counts(t, actuators),
                                      mask.excluded(t, actuators).sum(axis=1))
        if mask.examined is None:  # sorted by actuator: a tile's pairs found by search
            order = np.argsort(mask.actuator, kind="stable")
            by_actuator = replace(mask, start_s=mask.start_s[order], end_s=mask.end_s[order],
                                  actuator=mask.actuator[order], by_actuator=True)
            shuffled = rng.permutation(actuators)
            np.testing.assert_array_equal(by_actuator.excluded(t, shuffled),
                                          mask.excluded(t, shuffled))
