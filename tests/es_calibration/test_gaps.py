"""Gaps and holes in measured data: found, reported, and the samples they need left out.

Bags come from the hyperbolic law alone (law_bags.py): 90 s at 250 Hz on 2 x 2 actuators,
temperature at 10 Hz making one turn at 45 s. Cut out of them: 30 s of temperature over the
turn, 2 s of commands, 1.5 s of displacement, and 2 % of the displacement messages at random.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from es_calibration.calibrate import EXIT_BAD_INPUT, run
from es_calibration.data.align import GAP_DROPS, SPAN_DROPS, align
from es_calibration.data.gaps import COMMAND_SETTLING_S, find_gaps
from es_calibration.data.stamps import repeated
from es_calibration.search.residual import spectrum
from es_calibration.verdict import WRITTEN

from . import law_bags as lb
from .measured_bags import read_measured_bags

TEMP_CUT = (30.0, 60.0)  # [start, end) of the removed temperature messages [s]
COMMAND_CUT = (20.0, 22.0)
DISPLACEMENT_CUT = (70.0, 71.5)
#: Half-window of the dT/dt estimate at 10 Hz: 21 samples -> 10 periods (align.RATE_WINDOW_S).
RATE_HALF_WINDOW_S = 1.0


def _gapped(run_: lb.LawRun) -> lb.Series:
    series = lb.cut(run_.topics, "/dm/temperature", *TEMP_CUT)
    series = lb.cut(series, "/dm/command", *COMMAND_CUT)
    series = lb.cut(series, "/dm/displacement", *DISPLACEMENT_CUT)
    return lb.drop_random(series, "/dm/displacement", 0.02)


def _straight_line(run_: lb.LawRun) -> lb.Series:
    """Return the run with the temperature gap filled by a straight line (the old behaviour)."""
    t, v = run_.topics["/dm/temperature"]
    inside = (t >= TEMP_CUT[0]) & (t < TEMP_CUT[1])
    lo, hi = np.flatnonzero(inside)[[0, -1]]
    w = ((t[inside] - t[lo - 1]) / (t[hi + 1] - t[lo - 1]))[:, None, None]
    filled = v.copy()
    filled[inside] = v[lo - 1] * (1.0 - w) + v[hi + 1] * w
    return lb.drop_random({**run_.topics, "/dm/temperature": (t, filled)}, "/dm/displacement", 0.02)


def _calibrate(series: lb.Series, out: Path) -> dict[str, Any]:
    bag = lb.write(series, out / "bag")
    assert run([str(bag), "-o", str(out / "out"), "-q"]) in WRITTEN
    doc: dict[str, Any] = json.loads((out / "out" / "calibration.json").read_text())
    doc["report"] = (out / "out" / "report.md").read_text()
    return doc


@pytest.fixture(scope="module")
def law_run() -> lb.LawRun:
    return lb.law_run()


@pytest.fixture(scope="module")
def gapped(law_run: lb.LawRun, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return _calibrate(_gapped(law_run), tmp_path_factory.mktemp("gapped"))


@pytest.fixture(scope="module")
def bridged(law_run: lb.LawRun, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return _calibrate(_straight_line(law_run), tmp_path_factory.mktemp("bridged"))


def _last_before(times: np.ndarray, when: float) -> float:
    return float(times[times < when][-1])


def test_gaps_are_reported_with_their_times_and_lengths(law_run: lb.LawRun, gapped) -> None:
    series = _gapped(law_run)
    gaps = {g["topic"]: g for g in gapped["data"]["gaps"]}
    # random drops (one or two in a row here) make no gap: exactly the three holes are found
    assert len(gapped["data"]["gaps"]) == 3
    assert set(gaps) == {"/dm/temperature", "/dm/command", "/dm/displacement"}
    expected = {
        "/dm/temperature": (TEMP_CUT, 1.0 / lb.TEMPERATURE_RATE),
        "/dm/command": (COMMAND_CUT, 1.0 / lb.RATE),
        "/dm/displacement": (DISPLACEMENT_CUT, 1.0 / lb.RATE),
    }
    for topic, ((start, end), period) in expected.items():
        times = series[topic][0]
        last = _last_before(times, start)
        following = float(times[times >= end][0])
        assert gaps[topic]["start_s"] == pytest.approx(last, abs=1e-6)
        assert gaps[topic]["duration_s"] == pytest.approx(following - last, abs=1e-6)
        assert gaps[topic]["missing_samples"] == round((following - last) / period) - 1
    assert gaps["/dm/temperature"]["duration_s"] == pytest.approx(30.1, abs=1e-6)
    assert gaps["/dm/temperature"]["missing_samples"] == 300


def test_samples_needing_gap_data_are_excluded_and_counted(law_run: lb.LawRun, gapped) -> None:
    series = _gapped(law_run)
    t_disp = series["/dm/displacement"][0]
    t_temp = series["/dm/temperature"][0]
    t_cmd = series["/dm/command"][0]
    temp_lo = _last_before(t_temp, TEMP_CUT[0]) - RATE_HALF_WINDOW_S
    temp_hi = TEMP_CUT[1] + RATE_HALF_WINDOW_S
    in_temp = (t_disp >= temp_lo) & (t_disp <= temp_hi)
    cmd_lo = _last_before(t_cmd, COMMAND_CUT[0]) + 1.0 / lb.RATE - 1e-6
    in_cmd = (t_disp >= cmd_lo) & (t_disp <= COMMAND_CUT[1] + COMMAND_SETTLING_S)
    dropped = gapped["data"]["dropped"]
    assert dropped[GAP_DROPS["temperature"]] == int(in_temp.sum()) > 7000
    assert dropped[GAP_DROPS["command"]] == int(in_cmd.sum()) > 700
    gaps = {g["topic"]: g for g in gapped["data"]["gaps"]}
    assert gaps["/dm/temperature"]["excluded_samples"] == int(in_temp.sum())
    assert gaps["/dm/command"]["excluded_samples"] == int(in_cmd.sum())
    assert gaps["/dm/displacement"]["excluded_samples"] == 0
    # and the samples after the last temperature message (at 89.9 s, the record ends 89.998 s)
    outside = t_disp > t_temp[-1]
    assert dropped[SPAN_DROPS] == int((outside & ~(in_temp | in_cmd)).sum()) > 0
    kept = t_disp.size - int((in_temp | in_cmd | outside).sum())
    assert gapped["data"]["samples"] == kept


def test_no_kept_sample_lies_in_an_excluded_interval(law_run: lb.LawRun, tmp_path: Path) -> None:
    bag = lb.write(_gapped(law_run), tmp_path / "bag")
    aligned = align(read_measured_bags([bag]))
    t = aligned.t + aligned.start_time
    assert not np.any((t > TEMP_CUT[0] - RATE_HALF_WINDOW_S) & (t < TEMP_CUT[1]))
    assert not np.any((t > COMMAND_CUT[0]) & (t < COMMAND_CUT[1] + COMMAND_SETTLING_S))
    # residual runs stop at every gap: consecutive kept rows across one are not linked
    rows = np.arange(t.size)
    linked = aligned.linked(rows)
    steps = np.diff(aligned.t)
    assert not linked[steps > 1.0].any()
    assert linked[steps < 1.5 / lb.RATE].all()


def test_heldout_error_stays_at_the_noise_floor(gapped, bridged) -> None:
    floor = gapped["noise_floor_m"]
    assert floor == pytest.approx(lb.NOISE_M, rel=0.15)
    assert gapped["heldout_rms_after_m"] < 1.2 * floor
    # the same run with a straight line across the temperature gap, as before: the turn of
    # the temperature is lost and the held-out error is several times the noise
    assert bridged["data"]["gaps"] == []
    assert bridged["heldout_rms_after_m"] > 3.0 * bridged["noise_floor_m"]


def test_report_lists_the_gaps(gapped) -> None:
    report = gapped["report"]
    assert "never across a gap" in report
    for topic in ("/dm/temperature", "/dm/command", "/dm/displacement"):
        assert f"| `{topic}` |" in report
    assert "| 30.100 | 300 |" in report


def test_dropped_messages_and_lagging_stamps_make_no_gap() -> None:
    t = np.arange(2000) / 1000.0
    keep = np.ones(t.size, bool)
    keep[[100, 300, 301]] = False  # one drop and two in a row
    assert find_gaps("/dm/displacement", "displacement", t[keep]) == []
    keep[[700, 701, 702]] = False  # three in a row: a gap
    (gap,) = find_gaps("/dm/displacement", "displacement", t[keep])
    assert gap.start_s == pytest.approx(0.699) and gap.missing_samples == 3
    # a lagging recorder stamps runs of messages with one clock value: not gaps
    lagging = np.repeat(t[::5], 5)
    assert repeated(lagging).mean() > 0.7
    assert find_gaps("/dm/command", "command", lagging) == []
    with pytest.raises(ValueError, match="unknown role"):
        find_gaps("/dm/command", "setpoint", t)


def test_gaps_leaving_too_little_data_are_one_line(
    law_run: lb.LawRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # temperature only in the first and last 0.5 s: every sample needs the gap or its margin
    t, v = law_run.topics["/dm/temperature"]
    keep = (t < 0.5) | (t > 89.5)
    series = {**law_run.topics, "/dm/temperature": (t[keep], v[keep])}
    bag = lb.write(series, tmp_path / "bag")
    assert run([str(bag), "-o", str(tmp_path / "out")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "too short to fit" in err and GAP_DROPS["temperature"] in err


def test_topics_starting_late_or_ending_early_have_gaps_at_the_ends(
    law_run: lb.LawRun, tmp_path: Path
) -> None:
    series = lb.cut(law_run.topics, "/dm/temperature", 0.0, 5.0)
    series = lb.cut(series, "/dm/temperature", 87.0, 100.0)
    series = lb.cut(series, "/dm/command", 88.0, 100.0)
    aligned = align(read_measured_bags([lb.write(series, tmp_path / "bag")]))
    t_disp = series["/dm/displacement"][0]
    gaps = {(g.topic, round(g.start_s, 3)): g for g in aligned.gaps}
    lead = gaps[("/dm/temperature", round(float(t_disp[0]), 3))]
    assert lead.duration_s == pytest.approx(5.0 - t_disp[0], abs=1e-6)
    assert lead.missing_samples == 49  # messages due at 0.1 .. 4.9 s
    tail = gaps[("/dm/temperature", 86.9)]
    assert tail.duration_s == pytest.approx(t_disp[-1] - 86.9, abs=1e-6)
    command_tail = gaps[("/dm/command", 87.996)]
    assert command_tail.missing_samples == 500  # due at 88.000 .. 89.996 s
    t = aligned.t + aligned.start_time
    assert t[0] >= 5.0 + RATE_HALF_WINDOW_S and t[-1] <= 86.9 - RATE_HALF_WINDOW_S
    assert aligned.dropped[GAP_DROPS["temperature"]] == int(
        ((t_disp <= 5.0 + RATE_HALF_WINDOW_S) | (t_disp >= 86.9 - RATE_HALF_WINDOW_S)).sum()
    )


def test_samples_outside_the_temperature_topic_are_left_out_and_reported(
    tmp_path: Path,
) -> None:
    # a 1 Hz sensor: its first message 0.4 s into the record, its last 0.6 s before the
    # end (less than a gap's 3.5 periods), while the temperature moves by ~1 degC/s there
    run_ = lb.law_run(duration=30.0)
    t_temp, temp = run_.topics["/dm/temperature"]
    slow = np.flatnonzero(np.isclose((t_temp + 0.6) % 1.0, 0.0, atol=1e-6))
    series = {**run_.topics, "/dm/temperature": (t_temp[slow], temp[slow])}
    first, last = float(t_temp[slow][0]), float(t_temp[slow][-1])
    t_disp = series["/dm/displacement"][0]
    assert (first, t_disp[-1] - last) == pytest.approx((0.4, 0.6 - 0.5 / lb.RATE))
    doc = _calibrate(series, tmp_path)
    data = doc["data"]
    assert not [g for g in data["gaps"] if g["topic"] == "/dm/temperature"]
    before, after = int((t_disp < first).sum()), int((t_disp > last).sum())
    assert data["temperature_span"] == {
        "start_s": pytest.approx(first), "end_s": pytest.approx(last),
        "excluded_before": before, "excluded_after": after,
    }
    assert data["dropped"][SPAN_DROPS] == before + after > 2 * 100
    assert data["samples"] == t_disp.size - before - after
    assert f"{before} displacement samples before the first temperature message" in doc["report"]
    aligned = align(read_measured_bags([lb.write(series, tmp_path / "bag2")]))
    t = aligned.t + aligned.start_time
    assert t[0] >= first and t[-1] <= last


def test_a_run_cut_short_by_a_gap_does_not_coarsen_the_spectrum() -> None:
    rng = np.random.default_rng(0)
    resid = rng.standard_normal((2, 4100))
    contiguous = np.ones(4099, dtype=bool)
    contiguous[[1999, 2099]] = False  # runs of 2000, 100 and 2000 rows
    f, psd, segments = spectrum(resid, contiguous, 250.0)
    assert f[1] == pytest.approx(250.0 / 1024)
    assert segments >= 4 and np.all(np.isfinite(psd))


def test_lagging_stamps_before_a_gap_are_not_spread_across_it() -> None:
    t = np.round(np.arange(900) * 0.1, 6)
    lagging = np.repeat(t[::4], 4)[: t.size]  # runs of 4 messages share a stamp
    keep = (t < 30.0) | (t >= 60.0)
    (gap,) = find_gaps("/dm/temperature", "temperature", lagging[keep])
    assert gap.start_s == pytest.approx(29.9) and gap.duration_s == pytest.approx(30.1)
    assert gap.missing_samples == 300
