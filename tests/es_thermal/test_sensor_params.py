"""es_thermal.sensor_params: a sensor calibration -> the thermal node's parameters file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from es_thermal.errors import ThermalConfigError
from es_thermal.node_params import SPECS, config_from_parameters
from es_thermal.sensor_params import (
    CALIBRATED_BASE_DRIFT,
    CALIBRATED_STEP_GATE,
    SensorCalibration,
    sensor_parameters,
    write_sensor_params,
)


def test_the_file_is_the_nodes_parameters_and_loads(tmp_path: Path) -> None:
    path = tmp_path / "thermal_sensors.yaml"
    calibration = SensorCalibration(
        lag_s=[0.3, 0.2], offsets=[0.05, 0.0], offsets_sd=[0.01, 0.02], time_scale=0.02
    )
    write_sensor_params(path, calibration)
    document = yaml.safe_load(path.read_text(encoding="utf-8"))
    written = document["thermal"]["ros__parameters"]
    assert written["sensor_lag_tau"] == pytest.approx([15.0, 10.0])  # physical s
    assert written["sensor_offsets"] == [0.05, 0.0]
    assert all(isinstance(v, float) for v in written["sensor_offsets"])
    # What the node makes of it: every value passes its spec, the lags scaled back.
    specs = {spec.name: spec for spec in SPECS}
    assert all(specs[name].reason_to_reject(v) is None for name, v in written.items())
    values = {spec.name: spec.default for spec in SPECS}
    values.update(written, rows=1, cols=2, time_scale=0.02)
    config = config_from_parameters(values)
    assert np.ravel(config.sensor_tau).tolist() == pytest.approx([0.3, 0.2])
    assert np.ravel(config.sensor_offset_sd).tolist() == pytest.approx([0.01, 0.02])


def test_one_value_for_all_stays_a_scalar() -> None:
    written = sensor_parameters(SensorCalibration(lag_s=3.0))
    assert written == {"model.step_gate": CALIBRATED_STEP_GATE,
                       "model.base_drift": CALIBRATED_BASE_DRIFT, "sensor_lag_tau": 3.0,
                       "sensor_offsets": 0.0, "sensor_offsets_sd": 0.0}


@pytest.mark.parametrize(
    "calibration",
    [
        SensorCalibration(lag_s=-1.0),
        SensorCalibration(lag_s=[1.0, float("nan")]),
        SensorCalibration(offsets_sd=[-0.1]),
        SensorCalibration(lag_s=[]),
        SensorCalibration(time_scale=0.0),
    ],
)
def test_values_the_node_would_reject_are_refused(calibration: SensorCalibration) -> None:
    with pytest.raises(ThermalConfigError):
        sensor_parameters(calibration)
