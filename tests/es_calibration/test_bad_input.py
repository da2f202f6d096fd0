"""Bad measured data: one readable line on stderr and a non-zero exit, never a traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from es_calibration.calibrate import EXIT_BAD_INPUT, run
from es_calibration.data.align import (
    SPAN_DROPS,
    CalibrationInputError,
    MeasuredData,
)
from es_calibration.pipeline import calibrate
from es_calibration.verdict import WRITTEN
from es_msgs_py.bag import write_array_bag

from . import calibration_bags
from .measured_bags import read_measured_bags

RATE = 100.0


def _series(
    n: int = 1500, grid: tuple[int, int] = (1, 1)
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """A small valid measured-data set from the plant core (15 s at 100 Hz)."""
    result = calibration_bags.run(calibration_bags.scenario(*grid, duration=n / RATE, rate=RATE))
    dt = 1.0 / RATE
    return {
        "/dm/command": (result.time, result.command),
        "/dm/displacement": (result.time + dt, result.displacement_measured),
        "/dm/temperature/raw": (result.sensor_time, result.temperature_raw),
    }


@pytest.fixture(scope="module")
def series() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return _series()


def _fails(bag: Path, out: Path, capsys: pytest.CaptureFixture[str], *words: str) -> str:
    return _fails_with([str(bag)], out, capsys, *words)


def _fails_with(
    bags: list[str], out: Path, capsys: pytest.CaptureFixture[str], *words: str
) -> str:
    assert run([*bags, "-o", str(out)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    for word in words:
        assert word in err
    assert not (out / "calibration.json").exists()
    return err


def _shifted_bags(
    tmp_path: Path, parts: list[tuple[dict[str, tuple[np.ndarray, np.ndarray]], float]]
) -> list[str]:
    """Write each series, its stamps shifted by the given seconds, as bag0, bag1, ..."""
    bags = []
    for i, (data, shift) in enumerate(parts):
        bag = tmp_path / f"bag{i}"
        write_array_bag(bag, {k: (t + shift, v) for k, (t, v) in data.items()})
        bags.append(str(bag))
    return bags


def test_bag_without_needed_topics(series, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    write_array_bag(bag, {k: v for k, v in series.items() if k != "/dm/temperature/raw"})
    _fails(bag, tmp_path / "out", capsys, "missing", "/dm/temperature")


def test_mismatched_grid_sizes(series, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    t, cmd = series["/dm/command"]
    write_array_bag(bag, {**series, "/dm/command": (t, np.repeat(cmd, 2, axis=2))})
    _fails(bag, tmp_path / "out", capsys, "mismatched grid sizes")


def test_too_short_to_fit(series, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    write_array_bag(bag, {k: (t[:60], v[:60]) for k, (t, v) in series.items()})
    _fails(bag, tmp_path / "out", capsys, "too short")


def test_all_nan_displacement(series, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    t, z = series["/dm/displacement"]
    write_array_bag(bag, {**series, "/dm/displacement": (t, z * np.nan)})
    _fails(bag, tmp_path / "out", capsys, "too short")


@pytest.mark.parametrize("junk", [b"", b"\x89MCAP0\r\n" + b"\x00" * 64, b"not a bag at all"])
def test_corrupt_bag(series, tmp_path: Path, capsys, junk: bytes) -> None:
    bag = tmp_path / "bag"
    write_array_bag(bag, series)
    storage = next(bag.glob("*.mcap"))
    storage.write_bytes(junk)
    _fails(bag, tmp_path / "out", capsys)


def test_missing_path(tmp_path: Path, capsys) -> None:
    _fails(tmp_path / "nowhere", tmp_path / "out", capsys)


def test_nan_samples_are_dropped_and_counted(series, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    t, z = series["/dm/displacement"]
    z = z.copy()
    z[::50] = np.nan
    tc, cmd = series["/dm/command"]
    cmd = cmd.copy()
    cmd[7] = np.nan
    tt, temp = series["/dm/temperature/raw"]
    temp = temp.copy()
    temp[3] = np.nan
    write_array_bag(
        bag,
        {"/dm/command": (tc, cmd), "/dm/displacement": (t, z), "/dm/temperature/raw": (tt, temp)},
        storage="sqlite3",
    )
    assert run([str(bag), "-o", str(tmp_path / "out"), "-q"]) in WRITTEN
    doc = json.loads((tmp_path / "out" / "calibration.json").read_text())
    dropped = doc["data"]["dropped"]
    # NaN samples dropped first (before the first command, outside the temperature record)
    # are counted there; command edges mask pairs and drop no sample (every 50th sample is
    # NaN: a contiguous span of L samples holds at most L / 50 + 1 of them)
    taken = z[::50].size - dropped["displacement NaN"]
    ends = dropped.get(SPAN_DROPS, 0) + dropped.get("displacement before first command", 0)
    assert 0 <= taken <= ends / 50 + 2
    assert dropped["command NaN"] == 1
    assert dropped["temperature NaN"] == 1
    assert np.isfinite(doc["heldout_rms_after_m"])
    assert np.all(np.isfinite(doc["law"]["m2"]))
    assert doc["heldout_rms_after_m"] < 1.2 * doc["noise_floor_m"]


def test_installed_launcher_reports_one_line(tmp_path: Path) -> None:
    launcher = Path(sys.prefix) / "lib" / "es_calibration" / "calibrate"
    proc = subprocess.run(
        [str(launcher), str(tmp_path / "nowhere"), "-o", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == EXIT_BAD_INPUT
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("calibrate: ")


def test_consecutive_bags_are_joined(series, tmp_path: Path) -> None:
    half = series["/dm/command"][0].size // 2
    cut = series["/dm/command"][0][half]
    bags = []
    for i, keep in enumerate((lambda t: t < cut, lambda t: t >= cut)):
        bag = tmp_path / f"bag{i}"
        write_array_bag(bag, {k: (t[keep(t)], v[keep(t)]) for k, (t, v) in series.items()})
        bags.append(str(bag))
    assert run([*reversed(bags), "-o", str(tmp_path / "out"), "-q"]) in WRITTEN
    doc = json.loads((tmp_path / "out" / "calibration.json").read_text())
    # edges mask (sample, actuator) pairs, they drop no sample (edges.py)
    edged = doc["data"]["dropped"].get(SPAN_DROPS, 0)  # samples after the last temperature
    assert doc["data"]["samples"] + edged == series["/dm/displacement"][0].size
    assert doc["heldout_rms_after_m"] < 1.2 * doc["noise_floor_m"]


def test_overlapping_bags_are_refused(series, tmp_path: Path, capsys) -> None:
    bags = _shifted_bags(tmp_path, [(series, 0.0), (series, 5.0)])
    _fails_with(bags, tmp_path / "out", capsys, "overlap in time")


def test_bag_given_twice(series, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    write_array_bag(bag, series)
    _fails_with([str(bag), f"{tmp_path}/./bag"], tmp_path / "out", capsys, "given twice")


def _calibrate(bag: Path, out: Path) -> dict:
    assert run([str(bag), "-o", str(out), "-q"]) in WRITTEN
    return json.loads((out / "calibration.json").read_text())


def _lagging_stamps(t: np.ndarray, per_stamp: int) -> np.ndarray:
    """Stamps of a recorder that sees the clock only every ``per_stamp`` messages."""
    return np.repeat(t[::per_stamp], per_stamp)[: t.size]


def test_mostly_repeated_stamps_with_one_displacement_per_command_pair_by_order(
    series, tmp_path: Path
) -> None:
    """80 % repeated stamps (the lagging recorder): paired by order, fit down to the noise."""
    bag = tmp_path / "bag"
    write_array_bag(bag, {k: (_lagging_stamps(t, 5), v) for k, (t, v) in series.items()})
    doc = _calibrate(bag, tmp_path / "out")
    data = doc["data"]
    assert "paired by message order" in data["repeated_stamps"]
    # edges mask (sample, actuator) pairs, they drop no sample (edges.py)
    edged = data["dropped"].get(SPAN_DROPS, 0)  # samples after the last temperature
    assert data["samples"] + edged == series["/dm/displacement"][0].size
    assert "temperature stamps repeated" in data["repeated_stamps"]
    assert sum(data["dropped"].values()) == edged
    assert doc["heldout_rms_after_m"] < 1.2 * doc["noise_floor_m"]


def test_repeated_stamps_with_unequal_counts_drop_and_count_ambiguous_samples(
    series, tmp_path: Path
) -> None:
    t, z = series["/dm/displacement"]
    stamps = t.copy()
    stamps[1::5] = stamps[::5][: stamps[1::5].size]  # pairs (5j, 5j+1) share a stamp
    tc, cmd = series["/dm/command"]
    bag = tmp_path / "bag"
    write_array_bag(
        bag, {**series, "/dm/displacement": (stamps, z), "/dm/command": (tc[:-1], cmd[:-1])}
    )
    doc = _calibrate(bag, tmp_path / "out")
    ambiguous = 2 * stamps[1::5].size
    assert doc["data"]["dropped"]["displacement with ambiguous repeated stamp"] == ambiguous
    # edges mask (sample, actuator) pairs, they drop no sample (edges.py)
    edged = doc["data"]["dropped"].get(SPAN_DROPS, 0)  # samples after the last temperature
    assert doc["data"]["samples"] + edged == t.size - ambiguous
    assert "dropped" in doc["data"]["repeated_stamps"]
    assert doc["heldout_rms_after_m"] < 1.2 * doc["noise_floor_m"]


def test_too_little_unambiguous_data_is_one_line(series, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    lagging = {k: (_lagging_stamps(t, 5), v) for k, (t, v) in series.items()}
    tc, cmd = lagging["/dm/command"]
    write_array_bag(bag, {**lagging, "/dm/command": (tc[:-7], cmd[:-7])})
    _fails(bag, tmp_path / "out", capsys, "too little usable data", "ambiguous")


@pytest.mark.parametrize("topic", ["/dm/command", "/dm/displacement", "/dm/temperature/raw"])
def test_all_stamps_equal(series, tmp_path: Path, capsys, topic: str) -> None:
    """One stamp for a whole topic; commands also one fewer, so they cannot pair by order."""
    bag = tmp_path / "bag"
    data = {k: (t[:-1], v[:-1]) if k == "/dm/command" else (t, v) for k, (t, v) in series.items()}
    t, v = data[topic]
    data[topic] = (np.full_like(t, t[0]), v)
    write_array_bag(bag, data)
    _fails(bag, tmp_path / "out", capsys)


def test_empty_temperature_topic_counts_as_absent(series, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_array_bag(bag, {**series, "/dm/temperature": (np.zeros(0), np.zeros((0, 1, 1)))})
    measured = read_measured_bags([bag])
    assert measured.temperature_source == "/dm/temperature/raw"
    np.testing.assert_array_equal(
        measured.temperature[:, 0, 0], series["/dm/temperature/raw"][1][:, 0]
    )


def test_no_temperature_data(series, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    write_array_bag(
        bag,
        {
            **series,
            "/dm/temperature": (np.zeros(0), np.zeros((0, 1, 1))),
            "/dm/temperature/raw": (np.zeros(0), np.zeros((0, 1))),
        },
    )
    err = _fails(bag, tmp_path / "out", capsys, "missing", "/dm/temperature/raw")
    assert "empty: /dm/temperature, /dm/temperature/raw" in err


@pytest.mark.parametrize("topic", ["/dm/command", "/dm/displacement"])
def test_topic_without_messages(series, tmp_path: Path, capsys, topic: str) -> None:
    bag = tmp_path / "bag"
    write_array_bag(bag, {**series, topic: (np.zeros(0), np.zeros((0, 1, 1)))})
    _fails(bag, tmp_path / "out", capsys, "missing", topic)


@pytest.mark.parametrize("topic", [None, "/dm/command", "/dm/displacement", "/dm/temperature/raw"])
def test_single_message(series, tmp_path: Path, capsys, topic: str | None) -> None:
    bag = tmp_path / "bag"
    write_array_bag(
        bag, {k: (t[:1], v[:1]) if topic in (None, k) else (t, v) for k, (t, v) in series.items()}
    )
    _fails(bag, tmp_path / "out", capsys, "too short")


def test_stamps_going_backwards_are_read_in_stamp_order(series, tmp_path: Path) -> None:
    """A recorder writing out of order: messages are put back in stamp order."""
    bag = tmp_path / "bag"
    shuffled = {}
    for i, (k, (t, v)) in enumerate(series.items()):
        order = np.random.default_rng(i).permutation(t.size)
        shuffled[k] = (t[order], v[order])
    write_array_bag(bag, shuffled)
    measured = read_measured_bags([bag])
    np.testing.assert_allclose(measured.displacement_times, series["/dm/displacement"][0])
    np.testing.assert_array_equal(measured.displacement, series["/dm/displacement"][1])
    np.testing.assert_array_equal(measured.command, series["/dm/command"][1])


def test_backwards_stamps_in_measured_data_are_one_line(series) -> None:
    measured = MeasuredData(
        command_times=series["/dm/command"][0][::-1],
        command=series["/dm/command"][1],
        displacement_times=series["/dm/displacement"][0],
        displacement=series["/dm/displacement"][1],
        temperature_times=series["/dm/temperature/raw"][0],
        temperature=series["/dm/temperature/raw"][1][:, :, None],
    )
    with pytest.raises(CalibrationInputError, match="backwards") as err:
        calibrate(measured)
    assert "\n" not in str(err.value)


def test_mismatched_grid_sizes_between_bags(tmp_path: Path, capsys) -> None:
    small, wide = _series(400), _series(400, grid=(1, 2))
    bags = _shifted_bags(tmp_path, [(small, 0.0), (wide, 10.0)])
    _fails_with(bags, tmp_path / "out", capsys, "mismatched grid sizes")


def test_output_directory_that_cannot_be_created(series, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    write_array_bag(bag, series)
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    _fails(bag, blocker / "out", capsys, "cannot create output directory")


def test_old_executable_name_says_where_the_tool_moved() -> None:
    # `ros2 run es_feedforward calibrate` stays one release as an alias of the moved tool
    alias = Path(sys.prefix) / "lib" / "es_feedforward" / "calibrate"
    result = subprocess.run([str(alias), "--help"], capture_output=True, text=True,
                            timeout=180, check=False)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "ros2 run es_calibration calibrate" in result.stderr
    assert "usage: calibrate" in result.stdout
