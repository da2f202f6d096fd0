"""Lab-recording import: every format round-trips into a contract bag in SI units."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.io
import yaml
from support.labfiles import (
    Recording,
    flat_f,
    recording,
    write_csv,
    write_h5,
    write_map,
    write_mat,
    write_mat73,
    write_npz,
)

from es_msgs_py.bag import read_bag
from es_recordings.labimport import import_recording, load_map, parse_map
from es_recordings.labimport.cli import run

ROOT = Path(__file__).resolve().parents[2]
Writer = Callable[[Path, Recording], dict[str, Any]]
FORMATS: dict[str, tuple[str, Writer]] = {
    "mat_v5": (".mat", write_mat),
    "mat_v73": (".mat", write_mat73),
    "hdf5": (".h5", write_h5),
    "csv": (".csv", write_csv),
    "tsv": (".tsv", lambda p, r: write_csv(p, r, "\t")),
    "npz": (".npz", write_npz),
}


def _ns(seconds: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(seconds) * 1e9).astype(np.int64)


def _check_bag(bag: Path, rec: Recording, with_temperature: bool) -> None:
    series = read_bag(bag)
    expected = {"/dm/command", "/dm/displacement"} | (
        {"/dm/temperature/raw"} if with_temperature else set()
    )
    assert set(series) == expected
    for topic, truth in (("/dm/command", rec.command), ("/dm/displacement", rec.displacement)):
        got = series[topic]
        assert got.values is not None
        np.testing.assert_array_equal(_ns(got.times), _ns(rec.t))
        np.testing.assert_allclose(got.values, truth, rtol=1e-12, atol=1e-21)
    if with_temperature:
        temp = series["/dm/temperature/raw"]
        np.testing.assert_array_equal(_ns(temp.times), _ns(rec.temperature_t))
        np.testing.assert_allclose(temp.values, rec.temperature, rtol=1e-12)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("fmt", "storage"), [(fmt, "mcap") for fmt in FORMATS] + [("mat_v73", "sqlite3")]
)
def test_round_trip_every_format(tmp_path: Path, fmt: str, storage: str) -> None:
    suffix, writer = FORMATS[fmt]
    rec = recording()
    source = tmp_path / f"rec{suffix}"
    document = writer(source, rec)
    summary = import_recording(source, tmp_path / "bag", parse_map(document), storage)
    _check_bag(tmp_path / "bag", rec, "/dm/temperature/raw" in document["topics"])
    assert [t.dropped for t in summary.topics] == [0] * len(summary.topics)
    assert summary.topics[0].messages == len(rec.t)
    assert set(tmp_path.iterdir()) == {source, tmp_path / "bag"}  # no temporary left


def test_matlab_column_major_3x4_grid_comes_out_right(tmp_path: Path) -> None:
    """grid(r, c) = 10 r + c stored as MATLAB's grid(:)' rows: order F rebuilds the grid."""
    grid = 10.0 * np.arange(3)[:, None] + np.arange(4)[None, :]
    grids = np.stack([grid + k * 100 for k in range(5)])
    scipy.io.savemat(tmp_path / "rec.mat", {"u": flat_f(grids)})
    assert flat_f(grids)[0].tolist()[:4] == [0.0, 10.0, 20.0, 1.0]  # column-major on file
    document: dict[str, Any] = {"time": {"start": 0.0, "rate": 10.0},
                "topics": {"/dm/command": {"variable": "u", "unit": "V", "grid": [3, 4],
                                           "order": "F"}}}
    import_recording(tmp_path / "rec.mat", tmp_path / "bag", parse_map(document))
    values = read_bag(tmp_path / "bag")["/dm/command"].values
    assert values is not None
    np.testing.assert_array_equal(values, grids)
    assert values[0, 1, 2] == 12.0 and values[0, 2, 1] == 21.0
    # the same data read as row-major is a different (wrong) grid: the order matters
    document["topics"]["/dm/command"]["order"] = "C"
    import_recording(tmp_path / "rec.mat", tmp_path / "bag_c", parse_map(document))
    wrong = read_bag(tmp_path / "bag_c")["/dm/command"].values
    assert wrong is not None and wrong[0, 0, 1] == 10.0 != grids[0, 0, 1]


def test_matlab_3x4xN_array_keeps_its_indices(tmp_path: Path) -> None:
    grids = np.random.default_rng(1).normal(size=(6, 3, 4))
    scipy.io.savemat(tmp_path / "rec.mat", {"u": grids.transpose(1, 2, 0), "t": np.arange(6.0)})
    document = {"time": {"variable": "t"},
                "topics": {"/dm/command": {"variable": "u", "unit": "V", "grid": [3, 4],
                                           "order": "F"}}}
    import_recording(tmp_path / "rec.mat", tmp_path / "bag", parse_map(document))
    got = read_bag(tmp_path / "bag")["/dm/command"].values
    assert got is not None
    np.testing.assert_array_equal(got, grids)


def test_time_axis_last_in_hdf5(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Grids stored (3, 4, N): `auto` and `last` find time on the last axis, `first` cannot."""
    import h5py

    grids = np.random.default_rng(4).normal(size=(8, 3, 4))
    with h5py.File(tmp_path / "rec.h5", "w") as f:
        f["t"] = (np.arange(8) / 10.0)[:, None]  # an N x 1 time column
        f["u"] = grids.transpose(1, 2, 0)
    document: dict[str, Any] = {}
    for axis in ("auto", "last"):
        document = {"time": {"variable": "t"},
                    "topics": {"/dm/command": {"variable": "u", "unit": "V", "grid": [3, 4],
                                               "time_axis": axis}}}
        import_recording(tmp_path / "rec.h5", tmp_path / axis, parse_map(document))
        got = read_bag(tmp_path / axis)["/dm/command"].values
        assert got is not None
        np.testing.assert_array_equal(got, grids)
    document["topics"]["/dm/command"]["time_axis"] = "first"
    write_map(tmp_path / "map.yaml", document)
    assert run([str(tmp_path / "rec.h5"), "-o", str(tmp_path / "first"), "--map",
                str(tmp_path / "map.yaml")]) == 2
    assert "grid size mismatch: /dm/command needs 12 values per sample (3 x 4), 'u' has " \
        "shape (3, 4, 8)" in capsys.readouterr().err


def test_simulink_structure_with_time(tmp_path: Path) -> None:
    """Simulink's "structure with time" log: time + signals.values (+ a label string)."""
    t = np.arange(50) / 100.0
    values = np.random.default_rng(2).normal(size=(50, 2))
    scipy.io.savemat(tmp_path / "rec.mat", {"ScopeData": {
        "time": t[:, None], "signals": {"values": values, "label": "T1 T2", "dimensions": 2},
        "blockName": "rig/Scope"}})
    document = {"topics": {"/dm/temperature/raw": {"variable": "ScopeData", "unit": "degC",
                                                   "sensors": 2}}}
    import_recording(tmp_path / "rec.mat", tmp_path / "bag", parse_map(document))
    got = read_bag(tmp_path / "bag")["/dm/temperature/raw"]
    assert got.values is not None
    np.testing.assert_array_equal(got.values, values)
    np.testing.assert_array_equal(_ns(got.times), _ns(t))


def test_rates_differ_per_topic_and_kelvin_becomes_degc(tmp_path: Path) -> None:
    rec = recording(n=100)
    write_mat(tmp_path / "rec.mat", rec)
    document = {"topics": {
        "/dm/command": {"variable": "u", "unit": "V", "grid": [3, 4], "order": "F",
                        "time": {"start": 2.0, "rate": 5000.0}},
        "/dm/temperature/raw": {"variable": "T", "unit": "K", "sensors": 2,
                                "time": {"start": 2.0, "rate": 10.0}},
    }}
    import_recording(tmp_path / "rec.mat", tmp_path / "bag", parse_map(document))
    series = read_bag(tmp_path / "bag")
    np.testing.assert_array_equal(_ns(series["/dm/command"].times), _ns(2.0 + np.arange(100) / 5e3))
    np.testing.assert_array_equal(_ns(series["/dm/temperature/raw"].times),
                                  _ns(2.0 + np.arange(10) / 10.0))
    np.testing.assert_allclose(series["/dm/temperature/raw"].values, rec.temperature, rtol=1e-12)  # type: ignore[arg-type]
    np.testing.assert_allclose(series["/dm/command"].values, rec.command * 1e3, rtol=1e-12)  # type: ignore[arg-type]


def test_nan_samples_are_dropped_and_counted(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                              ) -> None:
    rec = recording(n=200)
    document = write_csv(tmp_path / "rec.csv", rec)
    document["topics"]["/dm/temperature/raw"] = {"columns": ["temp_a", "temp_b"], "unit": "degC",
                                                 "sensors": 2}
    write_map(tmp_path / "map.yaml", document)
    assert run([str(tmp_path / "rec.csv"), "-o", str(tmp_path / "bag"), "--map",
                str(tmp_path / "map.yaml")]) == 0
    out = capsys.readouterr().out
    # temperatures only every 10th row: the 180 empty cells are 20 runs of 9 NaN samples
    assert "/dm/temperature/raw: 20 messages" in out
    assert "dropped 180 sample(s) with NaN/inf in 20 run(s)" in out
    temp = read_bag(tmp_path / "bag")["/dm/temperature/raw"]
    np.testing.assert_array_equal(_ns(temp.times), _ns(rec.t[::10]))
    np.testing.assert_allclose(temp.values, rec.temperature, rtol=1e-12)  # type: ignore[arg-type]


def test_nan_runs_across_chunks_in_a_matlab_vector(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                                   ) -> None:
    import es_recordings.labimport.importer as importer

    monkeypatch.setattr(importer, "CHUNK_BYTES", 7 * 64)  # 7 samples: runs straddle chunks
    u = np.arange(40.0)
    u[5:9] = np.nan
    u[13:15] = np.inf
    u[39] = np.nan
    scipy.io.savemat(tmp_path / "rec.mat", {"u": u[:, None]})
    document = {"time": {"start": 0.0, "rate": 1.0},
                "topics": {"/dm/command": {"variable": "u", "unit": "V", "grid": [1, 1]}}}
    summary = import_recording(tmp_path / "rec.mat", tmp_path / "bag", parse_map(document))
    (topic,) = summary.topics
    assert (topic.messages, topic.dropped, topic.runs) == (33, 7, 3)
    got = read_bag(tmp_path / "bag")["/dm/command"]
    keep = np.isfinite(u)
    np.testing.assert_array_equal(got.values.ravel(), u[keep])  # type: ignore[union-attr]
    np.testing.assert_array_equal(_ns(got.times), _ns(np.arange(40.0)[keep]))


def test_inspect_lists_variables_and_guesses_a_usable_map(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    rec = recording()
    write_mat(tmp_path / "rec.mat", rec)
    assert run(["--inspect", str(tmp_path / "rec.mat")]) == 0
    out = capsys.readouterr().out
    assert "#   u: (300, 12) float64" in out
    assert "#   y: timeseries (Time y.Time, Data y.Data)" in out
    guessed = parse_map(yaml.safe_load(out))
    topics = {t.topic: t for t in guessed.topics}
    assert guessed.time is not None and guessed.time.variable == "t"
    assert topics["/dm/command"].variable == "u" and topics["/dm/command"].order == "F"
    assert topics["/dm/displacement"].variable == "y"
    assert topics["/dm/displacement"].shape == (3, 4)
    assert topics["/dm/temperature/raw"].shape == (2,)
    # the guess imports (units aside: the guess says V and m, the file holds mV and nm)
    write_map(tmp_path / "guess.yaml", yaml.safe_load(out))
    assert run([str(tmp_path / "rec.mat"), "-o", str(tmp_path / "bag"), "--map",
                str(tmp_path / "guess.yaml"), "-q"]) == 0
    assert read_bag(tmp_path / "bag")["/dm/displacement"].values.shape == (300, 3, 4)  # type: ignore[union-attr]


def test_inspect_groups_numbered_csv_columns(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    write_csv(tmp_path / "rec.csv", recording(n=20))
    assert run(["--inspect", str(tmp_path / "rec.csv")]) == 0
    out = capsys.readouterr().out
    assert "#   cmd_0..cmd_11: 12 columns (20,) float64" in out
    guessed = yaml.safe_load(out)
    assert guessed["topics"]["/dm/command"] == {"prefix": "cmd_", "unit": "V", "grid": [1, 12],
                                                "order": "C"}
    assert guessed["topics"]["/dm/displacement"]["prefix"] == "disp_"


def test_installed_launcher_imports(tmp_path: Path) -> None:
    """`ros2 run es_msgs_py import` runs the installed launcher under lib/es_recordings/."""
    launcher = Path(sys.prefix) / "lib" / "es_recordings" / "import"
    assert launcher.is_file(), "run ./scripts/bootstrap"
    rec = recording(n=50)
    write_map(tmp_path / "map.yaml", write_npz(tmp_path / "rec.npz", rec))
    proc = subprocess.run([str(launcher), str(tmp_path / "rec.npz"), "-o", str(tmp_path / "bag"),
                           "--map", str(tmp_path / "map.yaml"), "--storage", "sqlite3"],
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    assert "/dm/command: 50 messages from command [V]" in proc.stdout
    assert list((tmp_path / "bag").glob("*.db3"))
    _check_bag(tmp_path / "bag", rec, True)


def test_the_documented_example_map_imports_its_rig_log(tmp_path: Path) -> None:
    page = (ROOT / "docs" / "calibration.md").read_text()
    section = page.split("## Formats and the map", 1)[1]
    example = section.split("```yaml\n", 1)[1].split("```", 1)[0]
    (tmp_path / "map.yaml").write_text(example)
    rec = recording(n=100)
    scipy.io.savemat(tmp_path / "rig.mat", {
        "tout": rec.t[:, None],
        "u_amp": flat_f(rec.command) * 1e3,
        "interferometer": {"Time": rec.t, "Data": rec.displacement.transpose(1, 2, 0) * 1e9},
        **{f"ntc_{i}": rec.temperature[:, 0] + 273.15 + i for i in range(4)},
    })
    import_recording(tmp_path / "rig.mat", tmp_path / "bag", load_map(tmp_path / "map.yaml"))
    series = read_bag(tmp_path / "bag")
    np.testing.assert_allclose(series["/dm/command"].values, rec.command, rtol=1e-12)  # type: ignore[arg-type]
    np.testing.assert_allclose(series["/dm/displacement"].values, rec.displacement, rtol=1e-12)  # type: ignore[arg-type]
    temperature = series["/dm/temperature/raw"].values
    assert temperature is not None
    np.testing.assert_allclose(temperature, rec.temperature[:, :1] + np.arange(4), rtol=1e-12)
    np.testing.assert_array_equal(_ns(series["/dm/temperature/raw"].times),
                                  _ns(np.arange(10) / 10.0))
