"""Resolve a map against a recording: which arrays, which axis, which time base, per topic.

Everything that can be checked without reading the samples is checked here, before a bag
is started: missing variables, non-numeric ones, the grid size against the data, the
lengths of data and time variable, the time axis.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from es_recordings.labimport.errors import MapError, SourceError
from es_recordings.labimport.mapfile import ImportMap, TimeBase, TopicMap
from es_recordings.labimport.recording import FloatArray, Source, Timeseries, Variable
from es_recordings.labimport.sources import find_timeseries

_SHOWN_NAMES = 12


@dataclass(frozen=True)
class TopicPlan:
    """How to read one topic: its data arrays (each read along ``axes``) and time base.

    ``time_variable`` is read along ``time_axis`` and scaled by ``time.scale``; without it
    the stamps are ``time.start + i / time.rate``.
    """

    entry: TopicMap
    names: tuple[str, ...]
    axes: tuple[int, ...]
    samples: int
    time: TimeBase
    time_axis: int = 0

    @property
    def source_text(self) -> str:
        """The data's names for messages (the first and last of a column list)."""
        if len(self.names) > 2:
            return f"{self.names[0]}..{self.names[-1]}"
        return ", ".join(self.names)

    def layout(self, block: FloatArray) -> FloatArray:
        """Turn a block of samples (n, *sample shape) into (n, *topic shape).

        A sample shaped like the topic is taken as it is; any other sample of as many
        values is reshaped in the map's order (F: column-major, like MATLAB's reshape).
        """
        shape = self.entry.shape
        n = block.shape[0]
        if block.shape[1:] == shape:
            return block
        if self.entry.order == "C":
            return block.reshape(n, *shape)
        flipped = block.transpose(0, *range(block.ndim - 1, 0, -1))
        out = flipped.reshape(n, *shape[::-1])
        return out.transpose(0, *range(out.ndim - 1, 0, -1))


def _listing(variables: Mapping[str, Variable]) -> str:
    names = list(variables)
    more = f" and {len(names) - _SHOWN_NAMES} more" if len(names) > _SHOWN_NAMES else ""
    return ", ".join(names[:_SHOWN_NAMES]) + more if names else "nothing"


def _variable(source: Source, name: str, topic: str) -> Variable:
    variables = source.variables()
    var = variables.get(name)
    if var is None:
        raise SourceError(
            f"{source.path}: missing variable {name!r} for {topic} (the recording has: "
            f"{_listing(variables)})"
        )
    if not var.numeric:
        raise SourceError(f"{source.path}: variable {name!r} for {topic} is not numeric "
                          f"({var.dtype}); a MATLAB timeseries object must be saved as a struct")
    if not var.shape:
        raise SourceError(f"{source.path}: variable {name!r} for {topic} is a scalar, not samples")
    return var


def _prefixed(source: Source, prefix: str, topic: str) -> list[str]:
    pattern = re.compile(re.escape(prefix) + r"(\d+)$")
    numbered = sorted(
        (int(m.group(1)), name)
        for name in source.variables()
        if (m := pattern.match(name)) is not None
    )
    if not numbered:
        raise SourceError(
            f"{source.path}: no column {prefix}0, {prefix}1, ... for {topic} (the recording has: "
            f"{_listing(source.variables())})"
        )
    first = numbered[0][0]
    for expected, (number, _) in enumerate(numbered, first):
        if number != expected:
            raise SourceError(
                f"{source.path}: columns {prefix}{first}..{prefix}{numbered[-1][0]} for {topic} "
                f"miss {prefix}{expected}"
            )
    return [name for _, name in numbered]


def _time_vector(source: Source, time: TimeBase, topic: str) -> tuple[int, int]:
    """Return (samples, axis) of a time variable, which must be a vector."""
    assert time.variable is not None
    var = _variable(source, time.variable, topic)
    long_axes = [ax for ax, n in enumerate(var.shape) if n != 1]
    if len(long_axes) > 1:
        raise SourceError(
            f"{source.path}: time variable {time.variable!r} has shape {var.shape}, not a vector"
        )
    axis = long_axes[0] if long_axes else 0
    return var.shape[axis], axis


def _fits(sample: tuple[int, ...], entry: TopicMap) -> bool:
    """Return whether one sample of this shape holds the topic.

    It does when flat with as many values, shaped like the grid, or (sensor vectors) of any
    shape with as many values.
    """
    squeezed = tuple(n for n in sample if n != 1)
    count = int(np.prod(sample))
    if len(squeezed) <= 1 or entry.kind == "sensor":
        return count == entry.size
    return sample == entry.shape


def _data_axis(var: Variable, entry: TopicMap, samples: int | None, path: object) -> int:
    shape = var.shape
    last = len(shape) - 1
    wanted = {"first": [0], "last": [last], "auto": sorted({0, last})}
    candidates = [ax for ax in wanted[entry.time_axis]
                  if _fits(shape[:ax] + shape[ax + 1 :], entry)]
    if not candidates:
        grid = " x ".join(str(n) for n in entry.shape)
        raise SourceError(
            f"{path}: grid size mismatch: {entry.topic} needs {entry.size} values per sample "
            f"({grid}), {var.name!r} has shape {var.shape}"
        )
    if samples is None:
        return candidates[0]
    for ax in candidates:
        if shape[ax] == samples:
            return ax
    raise SourceError(
        f"{path}: lengths do not match the time base: {entry.topic}: {var.name!r} has "
        f"{shape[candidates[0]]} samples, the time variable {samples}"
    )


def plan_topic(source: Source, entry: TopicMap, default: TimeBase | None,
               series: Mapping[str, Timeseries]) -> TopicPlan:
    """Resolve one topic of the map against ``source``.

    Raises:
        SourceError: a variable is missing or unusable, the grid size or a length does not
            match.
        MapError: the topic has no time base.

    """
    time = entry.time
    if entry.variable is not None and entry.variable in series:
        struct = series[entry.variable]
        names: Sequence[str] = [struct.data]
        time = time or TimeBase(variable=struct.time)
    elif entry.variable is not None:
        names = [entry.variable]
    else:
        names = list(entry.columns) if entry.columns else _prefixed(source, entry.prefix or "",
                                                                    entry.topic)
    time = time or default
    if time is None:
        raise MapError(f"{entry.topic}: no time base: give 'time' (a variable, or start + rate) "
                       "for the topic or the whole map")
    samples, time_axis = (None, 0) if time.variable is None else _time_vector(
        source, time, entry.topic)
    variables = [_variable(source, name, entry.topic) for name in names]
    if len(variables) == 1:
        axis = _data_axis(variables[0], entry, samples, source.path)
        return TopicPlan(entry, tuple(names), (axis,), variables[0].shape[axis], time, time_axis)
    if len(variables) != entry.size:
        raise SourceError(
            f"{source.path}: grid size mismatch: {entry.topic} needs {entry.size} values per "
            f"sample, the map gives {len(variables)} columns"
        )
    expected = samples if samples is not None else variables[0].shape[0]
    against = "the time variable" if samples is not None else f"column {variables[0].name!r}"
    for var in variables:
        if len(var.shape) != 1:
            raise SourceError(f"{source.path}: column {var.name!r} for {entry.topic} has shape "
                              f"{var.shape}, not one value per sample")
        if var.shape[0] != expected:
            raise SourceError(f"{source.path}: lengths do not match the time base: "
                              f"{entry.topic}: {var.name!r} has {var.shape[0]} samples, "
                              f"{against} {expected}")
    return TopicPlan(entry, tuple(names), (0,) * len(names), variables[0].shape[0], time,
                     time_axis)


def plan_import(source: Source, import_map: ImportMap) -> list[TopicPlan]:
    """Resolve every topic of ``import_map`` against ``source`` (see :func:`plan_topic`)."""
    series = find_timeseries(source.variables())
    return [plan_topic(source, entry, import_map.time, series) for entry in import_map.topics]
