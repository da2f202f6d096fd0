"""A calibration's two parameters files and the one rule that ties them (pure: no rclpy).

What a user gives the bring-up, the launch file or the demo: a calibration directory (both
files taken from it, :meth:`CalibrationFiles.from_directory`) or the files one by one
(:meth:`CalibrationFiles.given`).

``calibrate`` writes the feedforward's file (``feedforward_params.yaml``) and the thermal
node's (``thermal_params.yaml``: the sensors' lag and offsets) into one directory. The
sensor's lag is undone once: by the thermal node's model when it has the thermal file (or a
lag from the scenario's design), else by the feedforward's temperature lead, calibrated for
users whose temperature comes from elsewhere. :func:`temperature_lead_s` decides; the graph
(:mod:`es_bringup.graph`), the bring-up, the launch file and the demo all go through it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import yaml

from es_bringup.errors import CalibrationFilesError
from es_feedforward.compensation import PREFIX as COMPENSATION_PREFIX
from es_feedforward.param_file import CALIBRATION_FILE_NAME as FEEDFORWARD_FILE_NAME
from es_node_runtime.param_yaml import floats_from_strings
from es_thermal.sensor_params import CALIBRATION_FILE_NAME as THERMAL_FILE_NAME

__all__ = [
    "FEEDFORWARD_FILE_NAME",
    "LAG_PARAMETER",
    "LEAD_PARAMETER",
    "THERMAL_FILE_NAME",
    "CalibrationFiles",
    "CalibrationFilesError",
    "node_parameters",
    "temperature_lead_s",
]

#: The feedforward's lead on the sensor temperature [s] (0: off).
LEAD_PARAMETER: Final = f"{COMPENSATION_PREFIX}temperature_lead_s"
#: The thermal node's sensor lag [s] (one value or one per sensor; es_thermal.node_params).
LAG_PARAMETER: Final = "sensor_lag_tau"


@dataclass(frozen=True)
class CalibrationFiles:
    """The parameters files a graph's feedforward and thermal nodes load.

    Attributes:
        feedforward: the feedforward's file, or ``None`` (defaults).
        thermal: the thermal node's file, or ``None`` (its temperature is taken as it comes:
            the feedforward's lead, if calibrated, undoes the sensor's lag).

    """

    feedforward: Path | None = None
    thermal: Path | None = None

    @classmethod
    def from_directory(cls, directory: Path) -> CalibrationFiles:
        """Return the files ``calibrate -o DIRECTORY`` wrote (the thermal one if present).

        Raises:
            CalibrationFilesError: no directory, or no feedforward file in it.

        """
        if not directory.is_dir():
            raise CalibrationFilesError(f"calibration directory {directory} does not exist")
        feedforward = directory / FEEDFORWARD_FILE_NAME
        if not feedforward.is_file():
            raise CalibrationFilesError(
                f"{directory} holds no {FEEDFORWARD_FILE_NAME}: not a calibration's output"
            )
        thermal = directory / THERMAL_FILE_NAME
        return cls(feedforward, thermal if thermal.is_file() else None)

    @classmethod
    def given(
        cls, directory: Path | None, feedforward: Path | None, thermal: Path | None
    ) -> CalibrationFiles:
        """Return the files of a command line: a calibration directory or single files.

        Raises:
            CalibrationFilesError: a directory and a file both given, a file that does not
                exist, or a directory without a feedforward file.

        """
        if directory is not None:
            if feedforward is not None or thermal is not None:
                raise CalibrationFilesError(
                    "give a calibration directory or the parameters files, not both"
                )
            return cls.from_directory(directory)
        for kind, path in (("feedforward", feedforward), ("thermal", thermal)):
            if path is not None and not path.is_file():
                raise CalibrationFilesError(f"{kind} parameters: no such file {path}")
        return cls(feedforward, thermal)


def _flatten(tree: Mapping[str, object], prefix: str = "") -> dict[str, object]:
    """Flatten nested parameter dicts (``compensation: {x: ..}``) to dotted names."""
    flat: dict[str, object] = {}
    for key, value in tree.items():
        if isinstance(value, Mapping):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def node_parameters(path: Path, node: str) -> dict[str, object]:
    """Return the flat parameters a ROS 2 parameters file gives the node ``node``.

    The ``/**`` wildcard's first, the node's own entries (with or without a leading ``/``)
    winning, as ROS applies them. Dot-less exponent strings are read as floats.

    Raises:
        CalibrationFilesError: unreadable file, or not a ROS 2 parameters file.

    """
    try:
        document, _ = floats_from_strings(yaml.safe_load(path.read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise CalibrationFilesError(
            f"cannot read parameters file {path}: {err}".splitlines()[0]
        ) from None
    if not isinstance(document, Mapping):
        raise CalibrationFilesError(f"{path} is not a ROS 2 parameters file")
    values: dict[str, object] = {}
    for key in ("/**", node, f"/{node}"):
        section = document.get(key)
        if isinstance(section, Mapping):
            parameters = section.get("ros__parameters")
            if not isinstance(parameters, Mapping):
                raise CalibrationFilesError(f"{path}: {key} has no ros__parameters mapping")
            values.update(_flatten(parameters))
    return values


def temperature_lead_s(
    feedforward: Mapping[str, object], thermal: Mapping[str, object] | None
) -> float:
    """Return the feedforward's ``compensation.temperature_lead_s`` for these parameters.

    Args:
        feedforward: the feedforward's parameters (its file's; empty: none).
        thermal: the thermal node's parameters (its file's and a scenario's design), or
            ``None`` when the temperature comes from elsewhere.

    Returns:
        0 when the thermal node is told the sensors' lag (``sensor_lag_tau``, even 0: it
        owns the lag, the lead would undo it a second time); else the feedforward's
        calibrated lead (0 without one).

    Raises:
        CalibrationFilesError: a lead that is not a number.

    """
    if thermal is not None and LAG_PARAMETER in thermal:
        return 0.0
    lead = feedforward.get(LEAD_PARAMETER, 0.0)
    if isinstance(lead, bool) or not isinstance(lead, int | float):
        raise CalibrationFilesError(f"{LEAD_PARAMETER} must be a number, got {lead!r}")
    return float(lead)
