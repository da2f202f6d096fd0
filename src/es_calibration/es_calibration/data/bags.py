"""Checks of measured-data bags (../shared/docs/interfaces.md, "Bags") shared by the reader.

A measured-data bag holds /dm/command, /dm/displacement and /dm/temperature (the per-actuator
estimate the feedforward uses, preferred) or /dm/temperature/raw (one sensor per actuator, or
a single sensor for the whole grid). The bags are read, streamed, by
:class:`~es_calibration.data.bagstream.BagRecording`; this module holds what it checks them
with: the list of bags, the topics a bag's metadata lists, the temperature on the grid. Every
problem becomes a :class:`CalibrationInputError` with one readable line.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml

from es_calibration.data.align import CalibrationInputError


def listed_topics(path: Path) -> set[str] | None:
    """Return the topics named in a closed bag's metadata.yaml (None when unknown)."""
    meta = path / "metadata.yaml"
    if not meta.is_file():
        return None
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        return {t["topic_metadata"]["name"] for t in info["topics_with_message_count"]}
    except (yaml.YAMLError, KeyError, TypeError) as err:
        raise CalibrationInputError(f"{path}: unreadable metadata.yaml ({err})") from None


def on_grid(values: np.ndarray, grid: tuple[int, int], path: Path) -> np.ndarray:
    """Return temperatures (N, R, C) from a grid topic or one sensor per actuator or one."""
    if values.ndim == 3:
        return values
    count = values.shape[1]
    if count == grid[0] * grid[1]:
        return values.reshape(-1, *grid)
    if count == 1:
        return np.broadcast_to(values[:, :, None], (values.shape[0], *grid)).copy()
    raise CalibrationInputError(
        f"{path}: mismatched grid sizes: {count} temperature sensors for a {grid[0]} x {grid[1]} "
        f"grid and no /dm/temperature (sensor positions are not in the bag)"
    )


def check_bag_list(paths: Sequence[str | Path]) -> None:
    """Refuse an empty list of bags and a bag given twice (under any spelling of its path).

    Raises:
        CalibrationInputError: no bag, or one bag given twice (one readable line).

    """
    if not paths:
        raise CalibrationInputError("no bag given")
    seen: dict[Path, str] = {}
    for p in paths:
        key = Path(p).resolve()
        if key in seen:
            raise CalibrationInputError(f"bag {p} given twice (also as {seen[key]})")
        seen[key] = str(p)
