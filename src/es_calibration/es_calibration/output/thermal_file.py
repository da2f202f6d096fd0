"""The thermal node's parameters file written from a :class:`Calibration` (its sensors' part).

The calibration finds the sensor's lag behind the actuator as the effect of the
``TEMPERATURE`` role (:class:`es_physics.effects.Role`; one effect at most holds it): its
time constant, one for the grid or one per actuator. The thermal node undoes that lag inside
its model (``sensor_lag_tau``, :mod:`es_thermal.node_params`) when it is given this file
with ``--params-file``; the feedforward's own lead is then switched off by the bring-up
(``es_bringup.calibration_files.temperature_lead_s``).

What is written (:func:`sensor_calibration`):

- ``sensor_lag_tau``: per sensor when the lag was fitted per actuator on one raw sensor per
  actuator (``/dm/temperature/raw``, row-major: sensor i is actuator i); one value for all
  sensors (the grid's median) otherwise; 0 when no lag was found or it did not hold on the
  record's halves. Physical seconds: the recording's lag divided by its ``time_scale``.
- ``model.step_gate``: ``es_thermal.sensor_params.CALIBRATED_STEP_GATE`` (a calibrated
  node follows stage steps) and ``model.base_drift``:
  ``es_thermal.sensor_params.CALIBRATED_BASE_DRIFT`` (a quiet stage between them); the
  node's defaults stay for uncalibrated runs.
- ``sensor_offsets`` and ``sensor_offsets_sd``: 0 (the calibration identifies no sensor
  offset: a common offset is absorbed by the law's temperature terms).

The lag's own 1-sigma uncertainty has no node parameter; it is in calibration.json's
``thermal_params`` section (:func:`thermal_section`) with the values written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from es_calibration.data.align import TEMPERATURE_RAW
from es_calibration.pipeline import AcceptedEffect, Calibration
from es_physics.effects import Role, get
from es_physics.effects.identifiable import Identifiable
from es_thermal.sensor_params import (
    CALIBRATION_FILE_NAME,
    SensorCalibration,
    sensor_parameters,
    write_sensor_params,
)

__all__ = ["CALIBRATION_FILE_NAME", "sensor_calibration", "thermal_section", "write_thermal_params"]


def _lag_effect(cal: Calibration) -> tuple[AcceptedEffect, str] | None:
    """Return the enabled effect that lags the sensor and its time constant's name."""
    for effect in cal.effects:
        found = get(effect.name)
        if effect.enabled and found.role is Role.TEMPERATURE:
            names = [n for n, kind in found.identifiable.items()
                     if kind is Identifiable.TIME_CONSTANT]
            if names:
                return effect, names[0]
    return None


def _lag_values(cal: Calibration) -> tuple[float | list[float], float | list[float]]:
    """Return the lag [s, recording time] and its 1-sigma, each one value or one per sensor."""
    found = _lag_effect(cal)
    if found is None:
        return 0.0, 0.0
    effect, name = found
    per_sensor = cal.aligned.temperature_source == TEMPERATURE_RAW
    if per_sensor and name in effect.per_actuator:
        values = [float(v) for v in effect.per_actuator[name]]
        sigmas = effect.per_actuator_uncertainties.get(name, [0.0] * len(values))
        return values, [float(s) if np.isfinite(s) else 0.0 for s in sigmas]
    sigma = float(effect.uncertainties.get(name, 0.0))
    return float(effect.parameters[name]), sigma if np.isfinite(sigma) else 0.0


def sensor_calibration(cal: Calibration, time_scale: float = 1.0) -> SensorCalibration:
    """Return what ``cal`` found about the temperature sensors (see the module docstring).

    Args:
        cal: the calibration.
        time_scale: the recording's time scale (a simulator's shortened run; 1: physical).

    """
    lag, _ = _lag_values(cal)
    return SensorCalibration(lag_s=lag, time_scale=time_scale)


def thermal_section(cal: Calibration, time_scale: float = 1.0) -> dict[str, Any]:
    """Return calibration.json's ``thermal_params`` section: the file and what it holds.

    ``sensor_lag_tau_sd`` is the lag's 1-sigma in the same (physical) seconds.

    Raises:
        es_thermal.errors.ThermalConfigError: a value outside the node's range.

    """
    _, sigma = _lag_values(cal)
    written = sensor_parameters(sensor_calibration(cal, time_scale))
    sd = np.asarray(sigma, float) / time_scale
    return {
        "file": CALIBRATION_FILE_NAME,
        "time_scale": time_scale,
        "temperature_topic": cal.aligned.temperature_source,
        **written,
        "sensor_lag_tau_sd": float(sd) if sd.ndim == 0 else sd.tolist(),
    }


def write_thermal_params(cal: Calibration, path: Path, time_scale: float = 1.0) -> None:
    """Write the thermal node's parameters file (the sensors' calibration) at ``path``.

    Raises:
        es_thermal.errors.ThermalConfigError: a value outside the node's range, or a
            ``time_scale`` that is not finite and > 0.
        OSError: the file cannot be written.

    """
    write_sensor_params(path, sensor_calibration(cal, time_scale))
