"""Bad measured data: one readable line on stderr and a non-zero exit, never a traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from es_feedforward.calibrate import EXIT_BAD_INPUT, run
from es_msgs_py.bag import write_array_bag

from . import calibration_bags

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
    assert run([str(bag), "-o", str(out)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    for word in words:
        assert word in err
    assert not (out / "calibration.json").exists()
    return err


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
    assert run([str(bag), "-o", str(tmp_path / "out"), "-q"]) == 0
    doc = json.loads((tmp_path / "out" / "calibration.json").read_text())
    dropped = doc["data"]["dropped"]
    assert dropped["displacement NaN"] == z[::50].size
    assert dropped["command NaN"] == 1
    assert dropped["temperature NaN"] == 1
    assert np.isfinite(doc["heldout_rms_after_m"])
    assert np.all(np.isfinite(doc["law"]["m2"]))
    assert doc["heldout_rms_after_m"] < 1.2 * doc["noise_floor_m"]


def test_installed_launcher_reports_one_line(tmp_path: Path) -> None:
    launcher = Path(sys.prefix) / "lib" / "es_feedforward" / "calibrate"
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
    assert run([*reversed(bags), "-o", str(tmp_path / "out"), "-q"]) == 0
    doc = json.loads((tmp_path / "out" / "calibration.json").read_text())
    assert doc["data"]["samples"] == series["/dm/displacement"][0].size
    assert doc["heldout_rms_after_m"] < 1.2 * doc["noise_floor_m"]


def test_overlapping_bags_are_refused(series, tmp_path: Path, capsys) -> None:
    bag = tmp_path / "bag"
    write_array_bag(bag, series)
    assert run([str(bag), str(bag), "-o", str(tmp_path / "out")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "overlap in time" in err
