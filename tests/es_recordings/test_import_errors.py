"""Lab-recording import, bad input: one line on stderr, exit 2, and no bag (nor a temporary)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.io
from support.labfiles import (
    recording,
    write_csv,
    write_h5,
    write_map,
    write_mat,
    write_mat73,
    write_npz,
)

from es_recordings.labimport.cli import run


def _fails(tmp_path: Path, capsys: pytest.CaptureFixture[str], source: Path,
           document: dict[str, Any] | None = None, map_text: str | None = None) -> str:
    """Run the import; check exit 2, one stderr line, nothing new in tmp_path; return it."""
    map_path = tmp_path / "map.yaml"
    if document is not None:
        write_map(map_path, document)
    elif map_text is not None:
        map_path.write_text(map_text)
    before = set(tmp_path.iterdir())
    status = run([str(source), "-o", str(tmp_path / "out" / "bag"), "--map", str(map_path)])
    captured = capsys.readouterr()
    assert status == 2
    assert captured.out == ""
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("import: "), captured.err
    assert "Traceback" not in captured.err
    assert set(tmp_path.iterdir()) == before  # no bag, no temporary, no new parent directory
    return lines[0]


def _mat(tmp_path: Path) -> tuple[Path, dict[str, Any]]:
    source = tmp_path / "rec.mat"
    return source, write_mat(source, recording(n=100))


def test_missing_variable(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source, document = _mat(tmp_path)
    document["topics"]["/dm/command"]["variable"] = "volts"
    line = _fails(tmp_path, capsys, source, document)
    assert "missing variable 'volts' for /dm/command" in line and "u, y.Time" in line


def test_missing_csv_column_prefix(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "rec.csv"
    document = write_csv(source, recording(n=30))
    document["topics"]["/dm/command"]["prefix"] = "u_"
    assert "no column u_0, u_1, ... for /dm/command" in _fails(tmp_path, capsys, source, document)


def test_gap_in_numbered_columns(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "rec.csv"
    source.write_text("t,u_0,u_1,u_3\n0,1,2,3\n1,1,2,3\n")
    document = {"time": {"variable": "t"},
                "topics": {"/dm/command": {"prefix": "u_", "unit": "V", "grid": [1, 3]}}}
    assert "columns u_0..u_3 for /dm/command miss u_2" in _fails(tmp_path, capsys, source,
                                                                 document)


@pytest.mark.parametrize("unit", ["mA", "volt", "um"])
def test_unit_not_in_the_list_or_of_another_quantity(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], unit: str
) -> None:
    source, document = _mat(tmp_path)
    document["topics"]["/dm/command"]["unit"] = unit
    line = _fails(tmp_path, capsys, source, document)
    if unit == "um":
        assert "unit 'um' is a length, /dm/command needs a voltage" in line
    else:
        assert f"unit '{unit}' is not one of V, mV, kV" in line


def test_lengths_do_not_match_the_time_base(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    rec = recording(n=100)
    scipy.io.savemat(tmp_path / "rec.mat", {"t": rec.t[:90], "u": rec.command.reshape(100, 12)})
    document = {"time": {"variable": "t"},
                "topics": {"/dm/command": {"variable": "u", "unit": "V", "grid": [3, 4]}}}
    line = _fails(tmp_path, capsys, tmp_path / "rec.mat", document)
    assert "lengths do not match the time base: /dm/command: 'u' has 100 samples, " \
        "the time variable 90" in line


def test_columns_of_different_lengths_in_hdf5(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    import h5py

    with h5py.File(tmp_path / "rec.h5", "w") as f:
        f["a"] = np.zeros(10)
        f["b"] = np.zeros(9)
    document = {"time": {"start": 0.0, "rate": 10.0},
                "topics": {"/dm/command": {"columns": ["a", "b"], "unit": "V", "grid": [1, 2]}}}
    assert "lengths do not match the time base: /dm/command: 'b' has 9 samples, column 'a' 10" \
        in _fails(tmp_path, capsys, tmp_path / "rec.h5", document)


@pytest.mark.parametrize("where", [3, 250])
def test_non_monotonic_time(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                            monkeypatch: pytest.MonkeyPatch, where: int) -> None:
    import es_recordings.labimport.importer as importer

    monkeypatch.setattr(importer, "CHUNK_BYTES", 100 * 148)  # 100 samples: 250 is late
    rec = recording(n=300)
    t = rec.t.copy()
    t[where] = t[where - 2]
    document = write_npz(tmp_path / "rec.npz", rec)
    np.savez(tmp_path / "rec.npz", t=t, command=rec.command,
             displacement=rec.displacement.reshape(300, 12), temperature=rec.temperature,
             temperature_t=rec.temperature_t)
    line = _fails(tmp_path, capsys, tmp_path / "rec.npz", document)
    assert f"/dm/command: time t is not increasing at sample {where}" in line


def test_negative_time(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scipy.io.savemat(tmp_path / "rec.mat", {"t": np.arange(-5.0, 5.0), "u": np.ones(10)})
    document = {"time": {"variable": "t"},
                "topics": {"/dm/command": {"variable": "u", "unit": "V", "grid": [1, 1]}}}
    assert "time t is negative at sample 0" in _fails(tmp_path, capsys, tmp_path / "rec.mat",
                                                      document)


def test_all_samples_nan(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scipy.io.savemat(tmp_path / "rec.mat", {"u": np.full(10, np.nan)})
    document = {"time": {"start": 0.0, "rate": 10.0},
                "topics": {"/dm/command": {"variable": "u", "unit": "V", "grid": [1, 1]}}}
    assert "/dm/command: no usable samples (10 in the recording, 10 with NaN/inf)" in _fails(
        tmp_path, capsys, tmp_path / "rec.mat", document)


@pytest.mark.parametrize(("entry", "expected"), [
    ({"grid": [4, 4]}, "needs 16 values per sample (4 x 4), 'u' has shape (100, 12)"),
    ({"grid": [2, 6], "variable": "y"}, "needs 12 values per sample (2 x 6), 'y.Data' has shape"),
])
def test_grid_size_does_not_match(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                  entry: dict[str, Any], expected: str) -> None:
    source, document = _mat(tmp_path)
    document["topics"]["/dm/command"].update(entry)
    assert expected in _fails(tmp_path, capsys, source, document)


def test_sensor_count_does_not_match(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source, document = _mat(tmp_path)
    document["topics"]["/dm/temperature/raw"]["sensors"] = 3
    assert "grid size mismatch: /dm/temperature/raw needs 3 values" in _fails(
        tmp_path, capsys, source, document)


Maker = Callable[[Path], dict[str, Any]]
MAKERS: dict[str, tuple[str, Maker]] = {
    "mat_v5": (".mat", lambda p: write_mat(p, recording(n=2000))),
    "mat_v73": (".mat", lambda p: write_mat73(p, recording(n=2000))),
    "hdf5": (".h5", lambda p: write_h5(p, recording(n=2000))),
    "csv": (".csv", lambda p: write_csv(p, recording(n=200))),
    "npz": (".npz", lambda p: write_npz(p, recording(n=2000))),
}


@pytest.mark.parametrize("fmt", list(MAKERS))
def test_truncated_file(tmp_path: Path, capsys: pytest.CaptureFixture[str], fmt: str) -> None:
    suffix, make = MAKERS[fmt]
    source = tmp_path / f"rec{suffix}"
    document = make(source)
    data = source.read_bytes()
    source.write_bytes(data[: int(len(data) * 0.6)])
    line = _fails(tmp_path, capsys, source, document)
    assert "truncated" in line or "corrupt" in line, line


@pytest.mark.parametrize("fmt", list(MAKERS))
def test_corrupt_file(tmp_path: Path, capsys: pytest.CaptureFixture[str], fmt: str) -> None:
    suffix, make = MAKERS[fmt]
    source = tmp_path / f"rec{suffix}"
    document = make(source)
    data = bytearray(source.read_bytes())
    rng = np.random.default_rng(5)
    start = 600 if fmt == "mat_v73" else 0  # past the v7.3 text header
    data[start : start + 400] = rng.integers(0, 256, 400, dtype=np.uint8).tobytes()
    source.write_bytes(bytes(data))
    line = _fails(tmp_path, capsys, source, document)
    assert "corrupt" in line or "not a number" in line or "fields" in line, line


def test_empty_and_unknown_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    document = {"time": {"start": 0.0, "rate": 10.0},
                "topics": {"/dm/command": {"variable": "u", "unit": "V", "grid": [1, 1]}}}
    (tmp_path / "empty.mat").write_bytes(b"")
    assert "empty" in _fails(tmp_path, capsys, tmp_path / "empty.mat", document)
    (tmp_path / "rec.xlsx").write_bytes(b"PK")
    assert "unknown recording format '.xlsx'" in _fails(tmp_path, capsys, tmp_path / "rec.xlsx",
                                                        document)
    assert "recording not found" in _fails(tmp_path, capsys, tmp_path / "nothing.mat", document)


@pytest.mark.parametrize(("text", "expected"), [
    ("topics: {/dm/command: {variable: u, unit: V, grid: [1, 1]\n", "is not valid YAML at line"),
    ("topics:\n  /dm/command: {variable: u, unit: V, grid: [1, 1], colour: red}\n"
     "time: {start: 0, rate: 1}\n", "unknown key(s) colour"),
    ("topic: {}\n", "unknown key(s) topic"),
    ("topics:\n  /dm/command: {variable: u, unit: V, grid: [1, 1]}\n",
     "/dm/command: no time base"),
    ("topics:\n  /dm/command: {variable: u, unit: V, grid: [1, 1]}\n"
     "time: {start: 0, rate: -5}\n", "time.rate must be a positive sample rate"),
    ("topics:\n  /dm/volts: {variable: u, unit: V, grid: [1, 1]}\n",
     "topic '/dm/volts' cannot be imported"),
    ("topics:\n  /dm/command: {variable: u, prefix: u_, unit: V, grid: [1, 1]}\n",
     "exactly one of 'variable', 'columns', 'prefix'"),
    ("topics:\n  /dm/temperature/raw: {variable: u, unit: degC, grid: [1, 1]}\n",
     "a sensor topic takes 'sensors: S'"),
    ("topics:\n  /dm/command: {variable: u, unit: V, grid: [1, 1], order: X}\n",
     "order must be C (row-major) or F (column-major)"),
    ("[1, 2]\n", "map must be a mapping"),
])
def test_unreadable_map(tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str,
                        expected: str) -> None:
    scipy.io.savemat(tmp_path / "rec.mat", {"u": np.ones(10)})
    line = _fails(tmp_path, capsys, tmp_path / "rec.mat", map_text=text)
    assert expected in line, line


def test_missing_map_and_existing_target(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    source, document = _mat(tmp_path)
    assert "cannot read map" in _fails(tmp_path, capsys, source)
    write_map(tmp_path / "map.yaml", document)
    (tmp_path / "bag").mkdir()
    status = run([str(source), "-o", str(tmp_path / "bag"), "--map", str(tmp_path / "map.yaml")])
    assert status == 2
    assert "exists already" in capsys.readouterr().err
    assert not list((tmp_path / "bag").iterdir())


def test_failure_in_a_later_topic_leaves_no_partial_bag(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    """The command topic is written in full before the temperature's time base fails."""
    rec = recording(n=100)
    temperature_t = rec.temperature_t.copy()
    temperature_t[-1] = 0.0
    np.savez(tmp_path / "rec.npz", t=rec.t, command=rec.command,
             displacement=rec.displacement.reshape(100, 12), temperature=rec.temperature,
             temperature_t=temperature_t)
    document = write_npz(tmp_path / "unused.npz", rec)
    (tmp_path / "unused.npz").unlink()
    line = _fails(tmp_path, capsys, tmp_path / "rec.npz", document)
    assert "/dm/temperature/raw: time temperature_t is not increasing at sample 9" in line
