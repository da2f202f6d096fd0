"""Read measured-data bags (../shared/docs/interfaces.md, "Bags") into :class:`MeasuredData`.

A measured-data bag holds /dm/command, /dm/displacement and /dm/temperature (the per-actuator
estimate the feedforward uses, preferred) or /dm/temperature/raw (one sensor per actuator, or
a single sensor for the whole grid). Several bags of one mirror are concatenated in time
order. Every problem becomes a :class:`CalibrationInputError` with one readable line.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import pairwise
from pathlib import Path

import numpy as np
import yaml

from es_calibration.data.align import (
    COMMAND,
    DISPLACEMENT,
    TEMPERATURE,
    TEMPERATURE_RAW,
    CalibrationInputError,
    MeasuredData,
)
from es_msgs_py.bag import BagError, TopicSeries, read_bag


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


def _grid_temperature(series: TopicSeries, grid: tuple[int, int], path: Path) -> np.ndarray:
    if series.values is None:
        raise CalibrationInputError(f"{path}: {series.topic} is not a Float64MultiArray")
    return on_grid(series.values, grid, path)


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


def read_measured_bag(path: str | Path) -> MeasuredData:
    """Read one measured-data bag; raise CalibrationInputError with one line on any problem.

    A topic without messages counts as absent: an empty /dm/temperature falls back to
    /dm/temperature/raw.
    """
    bag = Path(path)
    needed = [COMMAND, DISPLACEMENT]
    listed = listed_topics(bag)
    try:
        if listed is None:
            series = read_bag(bag)
        else:
            wanted = [t for t in (*needed, TEMPERATURE, TEMPERATURE_RAW) if t in listed]
            series = read_bag(bag, wanted)
    except BagError as err:
        raise CalibrationInputError(str(err)) from None
    empty = sorted(t for t, s in series.items() if len(s) == 0)
    series = {t: s for t, s in series.items() if len(s) > 0}
    missing = [t for t in needed if t not in series]
    temp_topic = next((t for t in (TEMPERATURE, TEMPERATURE_RAW) if t in series), None)
    if missing or temp_topic is None:
        need = [*missing] + ([] if temp_topic else [f"{TEMPERATURE} or {TEMPERATURE_RAW}"])
        raise CalibrationInputError(
            f"{bag}: bag without data on the needed topics: missing {', '.join(need)} "
            f"(with messages: {', '.join(sorted(series)) or 'none'}; "
            f"empty: {', '.join(empty) or 'none'})"
        )
    for topic in needed:
        values = series[topic].values
        if values is None or values.ndim != 3:
            raise CalibrationInputError(f"{bag}: {topic} is not a row x col grid topic")
    disp = series[DISPLACEMENT]
    cmd = series[COMMAND]
    assert disp.values is not None and cmd.values is not None
    grid = (int(disp.values.shape[1]), int(disp.values.shape[2]))
    if cmd.values.shape[1:] != grid:
        raise CalibrationInputError(
            f"{bag}: mismatched grid sizes: {COMMAND} is {cmd.values.shape[1]} x "
            f"{cmd.values.shape[2]}, {DISPLACEMENT} is {grid[0]} x {grid[1]}"
        )
    temp = series[temp_topic]
    return MeasuredData(
        command_times=cmd.times,
        command=cmd.values,
        displacement_times=disp.times,
        displacement=disp.values,
        temperature_times=temp.times,
        temperature=_grid_temperature(temp, grid, bag),
        temperature_source=temp_topic,
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


def read_measured_bags(paths: Sequence[str | Path]) -> MeasuredData:
    """Read and concatenate bags of one mirror (in start-time order)."""
    check_bag_list(paths)
    named = sorted(
        ((read_measured_bag(p), str(p)) for p in paths), key=lambda m: m[0].displacement_times[0]
    )
    if len(named) == 1:
        return named[0][0]
    for (a, name_a), (b, name_b) in pairwise(named):
        if b.displacement_times[0] <= a.displacement_times[-1]:
            raise CalibrationInputError(
                f"bags {name_a} and {name_b} overlap in time: give bags of one mirror recorded "
                "one after the other"
            )
    parts = [m for m, _ in named]
    shapes = {p.displacement.shape[1:] for p in parts}
    if len(shapes) > 1:
        raise CalibrationInputError(f"mismatched grid sizes between bags: {sorted(shapes)}")
    sources = {p.temperature_source for p in parts}
    if len(sources) > 1:
        raise CalibrationInputError("bags disagree on the temperature topic")
    return MeasuredData(
        command_times=np.concatenate([p.command_times for p in parts]),
        command=np.concatenate([p.command for p in parts]),
        displacement_times=np.concatenate([p.displacement_times for p in parts]),
        displacement=np.concatenate([p.displacement for p in parts]),
        temperature_times=np.concatenate([p.temperature_times for p in parts]),
        temperature=np.concatenate([p.temperature for p in parts]),
        temperature_source=parts[0].temperature_source,
    )
