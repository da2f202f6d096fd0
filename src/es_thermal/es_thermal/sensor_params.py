"""The thermal node's sensor calibration as a ROS 2 parameters file (pure: no rclpy).

A calibration that finds each sensor's lag behind its site and its offset hands them to the
thermal node, whose model undoes the lag (:mod:`es_thermal.kalman`) and subtracts the
offsets (:mod:`es_thermal.estimator`). :func:`sensor_parameters` gives the node's
parameters for a :class:`SensorCalibration`, :func:`write_sensor_params` writes them as a
parameters YAML for the node named ``thermal``, loadable with ``--params-file`` beside the
bring-up's own parameters (it holds nothing but the calibration's).

Lags are written physical, as the node's ``sensor_lag_tau`` is: a calibration on a
simulator's shortened recording passes the recording's ``time_scale``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from es_node_runtime.param_yaml import dump_parameters
from es_thermal.errors import ThermalConfigError
from es_thermal.network import per_sensor
from es_thermal.node_params import LAG_RANGE, OFFSET_RANGE, OFFSET_SD_RANGE

__all__ = [
    "CALIBRATION_FILE_NAME",
    "NODE_NAME",
    "SensorCalibration",
    "sensor_parameters",
    "write_sensor_params",
]

#: The thermal node's name (es_thermal.thermal_node.NODE_NAME, which imports rclpy).
NODE_NAME = "thermal"
#: Name of the file the calibration tool writes into its output directory (beside the
#: feedforward's, es_feedforward.param_file.CALIBRATION_FILE_NAME).
CALIBRATION_FILE_NAME = "thermal_params.yaml"


@dataclass(frozen=True)
class SensorCalibration:
    """What a calibration found about the temperature sensors.

    Each field is one value for every sensor or a sequence of one per sensor (the order of
    /dm/temperature/raw).

    Attributes:
        lag_s: first-order lag of each sensor behind its site [s] (0: none), in the time of
            the recording it was found in.
        offsets: what each sensor reads above its site [degC] (0 where not identified).
        offsets_sd: the offsets' 1-sigma uncertainty [degC] (0: none given).
        time_scale: the recording's time scale (a simulator's shortened scenario; 1 for a
            physical recording): the lags are divided by it.

    """

    lag_s: float | Sequence[float] = 0.0
    offsets: float | Sequence[float] = 0.0
    offsets_sd: float | Sequence[float] = 0.0
    time_scale: float = 1.0


def _checked(value: float | Sequence[float], name: str, limits: tuple[float, float]) -> object:
    """Return ``value`` as a float or a list of floats within ``limits``.

    Raises:
        ThermalConfigError: not finite, or outside ``limits`` (the message names ``name``).

    """
    values = np.atleast_1d(np.asarray(value, float))
    if values.ndim != 1 or values.size == 0:
        raise ThermalConfigError(f"{name}: one number or a list of one per sensor")
    values = per_sensor(values, values.size, name)
    low, high = limits
    if np.any(values < low) or np.any(values > high):
        raise ThermalConfigError(f"{name}={values.tolist()}: every value must lie in {limits}")
    if np.ndim(value) == 0:
        return float(values[0])
    return [float(v) for v in values]


#: Stage-step gate a calibrated thermal node runs with (``model.step_gate``; the node's own
#: default stays 0 so uncalibrated runs and the golden bags are unchanged). Measured on
#: bench_calibration_loop (2026-11-28, sensor_lag, thesis_dc_ac, whose stage moves in
#: steps): 0.316 -> 0.165 nm RMS (1.62x -> 0.85x of the ungated run without lag); thesis_ac
#: and the steady state unchanged.
CALIBRATED_STEP_GATE: Final = 4.0
#: Base-plate drift a calibrated thermal node assumes between stage steps
#: (``model.base_drift``, degC/sqrt(s); the node's default, 2e-2, stays for uncalibrated
#: runs): with the gate following the steps, the steady-state gain need not be that of a
#: fast-drifting stage, whose bandwidth the lag's inversion turned into noise. Measured on
#: bench_calibration_loop (2026-11-29, thesis_ac set point, steady state, 30 s or more after
#: a stage step): the estimate's RMS error 0.0107 -> 0.0047 degC behind the 5 s lag, 0.0052
#: -> 0.0034 degC without lag; tracking RMS 0.0200 -> 0.0130 nm and 0.0136 -> 0.0122 nm.
CALIBRATED_BASE_DRIFT: Final = 5e-3


def sensor_parameters(calibration: SensorCalibration) -> dict[str, object]:
    """Return the thermal node's parameters for ``calibration`` by name.

    ``model.step_gate``: :data:`CALIBRATED_STEP_GATE` (a calibrated node follows stage steps)
    and ``model.base_drift``: :data:`CALIBRATED_BASE_DRIFT` (a quiet stage between them).

    ``sensor_lag_tau`` (physical s), ``sensor_offsets`` and ``sensor_offsets_sd`` (degC):
    each a float (every sensor) or a list of floats (one per sensor), as given.

    Raises:
        ThermalConfigError: a value not finite or outside the node's parameter range, a
            list of per-sensor values that is empty, or a time scale that is not > 0.

    """
    scale = calibration.time_scale
    if not np.isfinite(scale) or scale <= 0.0:
        raise ThermalConfigError(f"time_scale must be finite and > 0, got {scale}")
    lags = np.asarray(calibration.lag_s, float) / scale
    lag_value: float | Sequence[float] = float(lags) if lags.ndim == 0 else lags.tolist()
    return {
        "model.step_gate": CALIBRATED_STEP_GATE,
        "model.base_drift": CALIBRATED_BASE_DRIFT,
        "sensor_lag_tau": _checked(lag_value, "sensor_lag_tau", LAG_RANGE),
        "sensor_offsets": _checked(calibration.offsets, "sensor_offsets", OFFSET_RANGE),
        "sensor_offsets_sd": _checked(
            calibration.offsets_sd, "sensor_offsets_sd", OFFSET_SD_RANGE
        ),
    }


def write_sensor_params(
    path: str | Path, calibration: SensorCalibration, node_name: str = NODE_NAME
) -> None:
    """Write ``calibration`` as a ROS 2 parameters YAML for the node ``node_name``.

    Floats are written so that every ROS 2 reader reads them as floats
    (:func:`es_node_runtime.param_yaml.dump_parameters`).

    Raises:
        ThermalConfigError: a value out of range (:func:`sensor_parameters`).
        OSError: the file cannot be written.

    """
    document = {node_name: {"ros__parameters": sensor_parameters(calibration)}}
    Path(path).write_text(dump_parameters(document), encoding="utf-8")
