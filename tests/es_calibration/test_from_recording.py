"""`calibrate REC.mat --map MAP.yaml`: a lab recording calibrates like the bag it imports to."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.io
from support.labfiles import flat_f, write_map

from es_calibration.calibrate import EXIT_BAD_INPUT, run
from es_calibration.verdict import WRITTEN
from es_msgs_py.bag import write_array_bag

from . import calibration_bags

RATE = 100.0
GRID = (2, 2)

MAP: dict[str, Any] = {
    "topics": {
        "/dm/command": {"variable": "u", "unit": "mV", "grid": list(GRID), "order": "F",
                        "time": {"variable": "t_u"}},
        "/dm/displacement": {"variable": "z", "unit": "nm", "grid": list(GRID), "order": "F",
                             "time": {"variable": "t_z", "unit": "ms"}},
        "/dm/temperature/raw": {"variable": "T", "unit": "K", "sensors": GRID[0] * GRID[1],
                                "time": {"start": 0.0, "rate": 10.0}},
    }
}


@pytest.fixture(scope="module")
def series() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    result = calibration_bags.run(calibration_bags.scenario(*GRID, duration=15.0, rate=RATE))
    return {
        "/dm/command": (result.time, result.command),
        "/dm/displacement": (result.time + 1.0 / RATE, result.displacement_measured),
        "/dm/temperature/raw": (result.sensor_time, result.temperature_raw),
    }


def _write_recording(path: Path, series: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """The same data as a Simulink log would hold them: MATLAB column-major, mV, nm, K."""
    t_u, u = series["/dm/command"]
    t_z, z = series["/dm/displacement"]
    t_T, T = series["/dm/temperature/raw"]
    np.testing.assert_allclose(t_T, np.arange(len(t_T)) / 10.0, atol=1e-12)
    scipy.io.savemat(path, {"t_u": t_u[:, None], "u": flat_f(u) * 1e3, "t_z": t_z * 1e3,
                            "z": flat_f(z) * 1e9, "T": T + 273.15})


def test_recording_calibrates_like_its_bag(series, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    write_array_bag(tmp_path / "bag", series)
    assert run([str(tmp_path / "bag"), "-o", str(tmp_path / "from_bag"), "-q"]) in WRITTEN
    _write_recording(tmp_path / "rec.mat", series)
    write_map(tmp_path / "map.yaml", MAP)
    assert run([str(tmp_path / "rec.mat"), "--map", str(tmp_path / "map.yaml"),
                "-o", str(tmp_path / "from_mat")]) == 0
    out = capsys.readouterr().out
    assert f"import {tmp_path / 'rec.mat'}: /dm/command: 1500 messages from u [mV]" in out
    from_bag = json.loads((tmp_path / "from_bag" / "calibration.json").read_text())
    from_mat = json.loads((tmp_path / "from_mat" / "calibration.json").read_text())
    for key in ("m1", "m2", "k1", "k2"):
        np.testing.assert_allclose(from_mat["law"][key], from_bag["law"][key], rtol=1e-9)
    assert from_mat["heldout_rms_after_m"] == pytest.approx(from_bag["heldout_rms_after_m"],
                                                            rel=1e-9)
    assert [p.name for p in (tmp_path / "from_mat").iterdir() if p.name.startswith(".")] == []


def _fails(argv: list[str], capsys: pytest.CaptureFixture[str], words: str, out: Path) -> None:
    assert run([*argv, "-o", str(out)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert words in err, err
    assert not (out / "calibration.json").exists()
    assert not [p for p in out.iterdir() if p.name.startswith(".import-")]


def test_recording_without_map_or_with_bad_data(series, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "rec.mat"
    _write_recording(rec, series)
    out = tmp_path / "out"
    _fails([str(rec)], capsys, "is a file, not a bag: give --map MAP.yaml", out)
    write_map(tmp_path / "map.yaml", MAP)
    write_array_bag(tmp_path / "bag", series)
    _fails([str(tmp_path / "bag"), "--map", str(tmp_path / "map.yaml")], capsys,
           "--map is given but no lab recording", out)
    bad = dict(MAP, topics=dict(MAP["topics"]))
    bad["topics"]["/dm/displacement"] = dict(MAP["topics"]["/dm/displacement"], unit="furlong")
    write_map(tmp_path / "bad.yaml", bad)
    _fails([str(rec), "--map", str(tmp_path / "bad.yaml")], capsys,
           "unit 'furlong' is not one of", out)
    t_u, u = series["/dm/command"]
    scipy.io.savemat(tmp_path / "short.mat", {"t_u": t_u[:-5], "u": flat_f(u) * 1e3,
                                              "t_z": t_u * 1e3, "z": flat_f(u),
                                              "T": np.zeros((150, 4))})
    _fails([str(tmp_path / "short.mat"), "--map", str(tmp_path / "map.yaml")], capsys,
           "lengths do not match the time base", out)
