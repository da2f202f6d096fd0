"""The thermal node's parameters file ``calibrate`` writes beside the feedforward's (issue 38).

Data from the independent generator (testing/standgen): a 2 x 2 stand whose NTCs lag their
actuators by 2 s (one raw sensor per actuator). The file must hold what calibration.json
reports (the lag divided by the recording's ``--time-scale``), pass the thermal node's own
parameter specs and mapping, and a clean stand's file must say "no lag".
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from standgen import StandConfig, simulate, write_bag
from standgen.effects import Effects, SensorLag

from es_calibration.calibrate import run
from es_thermal.node_params import SPECS, config_from_parameters
from es_thermal.sensor_params import CALIBRATED_BASE_DRIFT, CALIBRATED_STEP_GATE

LAG_S = 2.0
TIME_SCALE = 0.5
STAND = StandConfig(rows=2, cols=2, rate_hz=500.0, temperature_rate_hz=10.0, duration_s=20.0,
                    noise_m=0.5e-9, seed=7)


def _calibrated(root: Path, config: StandConfig, *extra: str) -> tuple[dict[str, Any], Path]:
    write_bag(simulate(config), root / "bag")
    status = run([str(root / "bag"), "-o", str(root / "out"), "-q",
                  "--candidates", "sensor_lag", *extra])
    assert status in (0, 3), status  # trusted or provisional: the files are written
    doc = json.loads((root / "out" / "calibration.json").read_text())
    return doc, root / "out" / doc["thermal_params"]["file"]


@pytest.fixture(scope="module")
def lagging(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path]:
    config = replace(STAND, effects=Effects(sensor_lag=SensorLag(LAG_S)))
    return _calibrated(tmp_path_factory.mktemp("lag"), config,
                       "--time-scale", str(TIME_SCALE))


def _node_values(path: Path) -> dict[str, object]:
    document = yaml.safe_load(path.read_text(encoding="utf-8"))  # floats written with a dot
    assert isinstance(document, dict)
    assert list(document) == ["thermal"]
    values: dict[str, object] = document["thermal"]["ros__parameters"]
    return values


def test_the_file_holds_what_calibration_json_reports(
    lagging: tuple[dict[str, Any], Path],
) -> None:
    doc, path = lagging
    assert path.name == "thermal_params.yaml" and path.parent.joinpath(
        "feedforward_params.yaml").is_file()
    (lag,) = [e for e in doc["effects"] if e["name"] == "sensor_lag"]
    section = doc["thermal_params"]
    written = _node_values(path)
    for name in ("model.step_gate", "model.base_drift", "sensor_lag_tau", "sensor_offsets",
                 "sensor_offsets_sd"):
        assert written[name] == section[name], name
    # physical: the recording's lag over its time scale, per sensor when fitted per actuator
    taus = lag["per_actuator"].get("tau_s", lag["parameters"]["tau_s"])
    assert np.asarray(written["sensor_lag_tau"]) == pytest.approx(
        np.asarray(taus) / TIME_SCALE)
    assert np.all(np.abs(np.asarray(written["sensor_lag_tau"]) * TIME_SCALE - LAG_S)
                  < 0.2 * LAG_S)
    assert section["time_scale"] == TIME_SCALE
    assert section["temperature_topic"] == "/dm/temperature/raw"
    assert np.all(np.asarray(section["sensor_lag_tau_sd"]) > 0)


def test_the_thermal_node_takes_the_file(lagging: tuple[dict[str, Any], Path]) -> None:
    doc, path = lagging
    written = _node_values(path)
    specs = {spec.name: spec for spec in SPECS}
    assert all(specs[name].reason_to_reject(v) is None for name, v in written.items())
    values: dict[str, object] = {spec.name: spec.default for spec in SPECS}
    values.update(written, rows=2, cols=2, time_scale=TIME_SCALE, sample_rate=10.0)
    config = config_from_parameters(values)
    # what the node's model uses: the lag in the recording's time again, one per sensor
    taus = np.broadcast_to(np.ravel(config.sensor_tau), (4,))
    assert taus == pytest.approx(np.broadcast_to(
        np.asarray(doc["thermal_params"]["sensor_lag_tau"]) * TIME_SCALE, (4,)))


def test_a_stand_without_lag_writes_no_lag(tmp_path: Path) -> None:
    doc, path = _calibrated(tmp_path, STAND)
    assert [e["name"] for e in doc["effects"]] == []
    assert _node_values(path) == {
        "model.step_gate": CALIBRATED_STEP_GATE, "model.base_drift": CALIBRATED_BASE_DRIFT,
        "sensor_lag_tau": 0.0, "sensor_offsets": 0.0, "sensor_offsets_sd": 0.0,
    }


def test_a_bad_time_scale_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    status = run([str(tmp_path / "bag"), "-o", str(tmp_path / "out"), "--time-scale", "0"])
    assert status == 2
    assert capsys.readouterr().err.count("\n") == 1
