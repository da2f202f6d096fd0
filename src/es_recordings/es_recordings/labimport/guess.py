"""``import --inspect``: list a recording's variables and guess a map to start from.

The guess is YAML that :func:`es_recordings.labimport.mapfile.parse_map` accepts whenever a
topic could be guessed: a time variable by its name (``t``, ``time``, ``timestamp``...), the
topics by keywords in the variable, struct or column-prefix names (``cmd``/``volt``,
``disp``/``pos``, ``setpoint``/``ref``, ``temp``/``ntc``, ``heat``), the unit as the
contract's own (V, m, degC, W: check them), the grid from the sample shape (square when
the sample is flat and its size a square, else 1 x K), order F for MATLAB files.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

import yaml

from es_msgs_py.topic_names import (
    COMMAND,
    DISPLACEMENT,
    HEAT_LOAD,
    SETPOINT,
    TEMPERATURE_RAW,
)
from es_recordings.labimport.mapfile import TOPICS, UNITS
from es_recordings.labimport.recording import Source, Variable
from es_recordings.labimport.sources import find_timeseries

#: Name patterns (on the last name part, case-insensitive) that suggest each topic.
KEYWORDS: Final[Mapping[str, str]] = {
    SETPOINT: r"setpoint|set_point|reference|^ref",
    COMMAND: r"cmd|command|volt|^u$|^v$",
    DISPLACEMENT: r"disp|pos|stroke|^y$|^z$|^d$",
    TEMPERATURE_RAW: r"temp|ntc|^T$",
    HEAT_LOAD: r"heat|load",
}
_TIME_NAMES: Final = re.compile(r"^(t|time|times|timestamp|time_s|t_s|tout)$", re.IGNORECASE)
_NUMBERED: Final = re.compile(r"^(.*?\D)(\d+)$")


@dataclass(frozen=True)
class _Candidate:
    """A guessed data source: one variable (or struct) or a numbered column group."""

    key: str  # the map's value: variable name or column prefix
    is_prefix: bool
    sample: tuple[int, ...]  # shape of one sample
    time: str | None  # a timeseries' own time variable
    own_rate: bool = False  # its length matches no time variable: it needs its own rate


def _leaf(name: str) -> str:
    return re.split(r"[./]", name)[-1]


def _groups(variables: Mapping[str, Variable]) -> dict[str, list[str]]:
    groups: dict[str, list[str]] = {}
    for name, var in variables.items():
        match = _NUMBERED.match(name)
        if match and len(var.shape) == 1:
            groups.setdefault(match.group(1), []).append(name)
    return {prefix: names for prefix, names in groups.items() if len(names) > 1}


def describe(source: Source) -> list[str]:
    """Return one line per variable, column group and timeseries: name, shape, dtype."""
    variables = source.variables()
    groups = _groups(variables)
    grouped = {name for names in groups.values() for name in names}
    lines = []
    for name, var in variables.items():
        if name not in grouped:
            note = "" if var.numeric else " (not numeric)"
            lines.append(f"{name}: {var.shape} {var.dtype}{note}")
    for names in groups.values():
        var = variables[names[0]]
        lines.append(f"{names[0]}..{names[-1]}: {len(names)} columns {var.shape} {var.dtype}")
    for name, series in find_timeseries(variables).items():
        lines.append(f"{name}: timeseries (Time {series.time}, Data {series.data})")
    return lines


def _time_variable(variables: Mapping[str, Variable], used: set[str]) -> str | None:
    for name, var in variables.items():
        if (name not in used and var.numeric and _TIME_NAMES.match(_leaf(name))
                and sum(n != 1 for n in var.shape) == 1):
            return name
    return None


def _candidates(variables: Mapping[str, Variable], samples: int | None) -> list[_Candidate]:
    series = find_timeseries(variables)
    inner = {s.time for s in series.values()} | {s.data for s in series.values()}
    groups = _groups(variables)
    grouped = {name for names in groups.values() for name in names}
    found = [
        _Candidate(name, False, variables[s.data].shape[:-1] if len(variables[s.data].shape) > 2
                   else variables[s.data].shape[1:], s.time)
        for name, s in series.items()
    ]
    found += [_Candidate(prefix, True, (len(names),), None) for prefix, names in groups.items()]
    for name, var in variables.items():
        if name in inner or name in grouped or not var.numeric or not var.shape:
            continue
        last_is_time = samples is not None and var.shape[-1] == samples != var.shape[0]
        sample = var.shape[:-1] if last_is_time else var.shape[1:]
        own_rate = samples is not None and samples not in (var.shape[0], var.shape[-1])
        found.append(_Candidate(name, False, sample, None, own_rate))
    return found


def _entry(topic: str, candidate: _Candidate, matlab: bool) -> dict[str, Any]:
    kind, quantity = TOPICS[topic]
    unit = next(name for name, u in UNITS.items() if u.quantity == quantity and u.scale == 1.0
                and u.offset == 0.0)
    entry: dict[str, Any] = {"prefix" if candidate.is_prefix else "variable": candidate.key,
                             "unit": unit}
    size = 1
    for n in candidate.sample:
        size *= n
    if kind == "sensor":
        entry["sensors"] = size
    elif len(candidate.sample) == 2:
        entry["grid"] = list(candidate.sample)
    else:
        side = round(size**0.5)
        entry["grid"] = [side, side] if side * side == size else [1, size]
        if size > 1:
            entry["order"] = "F" if matlab else "C"
    if candidate.own_rate:
        entry["time"] = {"start": 0.0, "rate": 1000.0}
    return entry


def guess_map(source: Source) -> str:
    """Return the listing (as YAML comments) and a guessed map of ``source`` as YAML text."""
    variables = source.variables()
    series_time = {s.time for s in find_timeseries(variables).values()}
    time = _time_variable(variables, series_time)
    samples = None
    if time is not None:
        samples = max(variables[time].shape)
    matlab = source.path.suffix.lower() == ".mat"
    topics: dict[str, Any] = {}
    unmatched = []
    notes = []
    for candidate in _candidates(variables, samples):
        if candidate.key == time:
            continue
        leaf = _leaf(candidate.key.rstrip("_"))
        topic = next((t for t, pattern in KEYWORDS.items()
                      if t not in topics and re.search(pattern, leaf, re.IGNORECASE)), None)
        if topic is None:
            unmatched.append(candidate.key)
            continue
        topics[topic] = _entry(topic, candidate, matlab)
        if candidate.own_rate:
            notes.append(f"# {candidate.key}: its length is not the time variable's: set its rate")
    document: dict[str, Any] = {}
    if time is not None:
        document["time"] = {"variable": time, "unit": "s"}
    elif any(c.time is None for c in _candidates(variables, None)):
        document["time"] = {"start": 0.0, "rate": 1000.0}
        notes.append("# no time variable found: set the sample rate (Hz) of the time base")
    document["topics"] = topics
    if not topics:
        notes.append("# no variable matched a topic: add the topics by hand")
    lines = [f"# import map guessed from {source.path} by `import --inspect`: check every",
             "# entry (units, grid, order) before importing.", "# variables:"]
    lines += [f"#   {line}" for line in describe(source)]
    if unmatched:
        lines.append(f"# not matched to a topic: {', '.join(unmatched)}")
    lines += notes
    body = yaml.safe_dump(document, sort_keys=False, default_flow_style=None)
    return "\n".join(lines) + "\n" + body
