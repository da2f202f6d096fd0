"""The import map: which variable or column holds each topic, in which unit, shape and time.

A map is a YAML file::

    time: {variable: t, unit: s}          # default time base of every topic (optional)
    topics:
      /dm/command:
        variable: u                       # a variable (or a Simulink-like struct with
                                          # Time + Data fields), or
        # columns: [u_0, u_1, u_2]        # a list of 1-D variables/columns, one per value, or
        # prefix: u_                      # every column u_0 .. u_N (numbered from 0)
        unit: V
        grid: [3, 4]                      # rows, cols (/dm/temperature/raw: sensors: S)
        order: F                          # how a flat sample of R*C values fills the grid:
                                          # C row-major (default), F column-major (MATLAB)
        time_axis: auto                   # auto (default), first or last
        time: {start: 0.0, rate: 5000.0}  # this topic's own time base (else the default)

A time base is either ``{variable: NAME, unit: s|ms|us|ns}`` or ``{start: S, rate: HZ}``
(start in seconds, default 0). Values are converted to the contract's units (V, m, degC,
W) with :data:`UNITS`, the one table of units the importer knows. Pure (yaml only).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal

import yaml

from es_msgs_py.topic_names import (
    COMMAND,
    DISPLACEMENT,
    HEAT_LOAD,
    SETPOINT,
    TEMPERATURE,
    TEMPERATURE_RAW,
)
from es_recordings.labimport.errors import MapError

Kind = Literal["grid", "sensor"]


@dataclass(frozen=True)
class Unit:
    """A unit: the quantity it measures and ``si = value * scale + offset``."""

    quantity: str
    scale: float
    offset: float = 0.0


#: Every unit a map may name, converted to the contract's unit of its quantity.
UNITS: Final[Mapping[str, Unit]] = {
    "V": Unit("voltage", 1.0),
    "mV": Unit("voltage", 1e-3),
    "kV": Unit("voltage", 1e3),
    "m": Unit("length", 1.0),
    "mm": Unit("length", 1e-3),
    "um": Unit("length", 1e-6),
    "nm": Unit("length", 1e-9),
    "degC": Unit("temperature", 1.0),
    "K": Unit("temperature", 1.0, -273.15),
    "W": Unit("power", 1.0),
    "mW": Unit("power", 1e-3),
}
#: Units of a time variable, in seconds.
TIME_UNITS: Final[Mapping[str, float]] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}

#: The topics an import can write: (array kind, quantity of their unit).
TOPICS: Final[Mapping[str, tuple[Kind, str]]] = {
    COMMAND: ("grid", "voltage"),
    DISPLACEMENT: ("grid", "length"),
    SETPOINT: ("grid", "length"),
    TEMPERATURE: ("grid", "temperature"),
    TEMPERATURE_RAW: ("sensor", "temperature"),
    HEAT_LOAD: ("grid", "power"),
}
ORDERS: Final = ("C", "F")
TIME_AXES: Final = ("auto", "first", "last")

_TOPIC_KEYS: Final = frozenset(
    {"variable", "columns", "prefix", "unit", "grid", "sensors", "order", "time_axis", "time"}
)
_TIME_KEYS: Final = frozenset({"variable", "unit", "start", "rate"})
_MAP_KEYS: Final = frozenset({"time", "topics"})


@dataclass(frozen=True)
class TimeBase:
    """A time variable (``variable`` in ``scale`` seconds) or ``start`` + ``rate`` (s, Hz)."""

    variable: str | None = None
    scale: float = 1.0
    start: float = 0.0
    rate: float | None = None


@dataclass(frozen=True)
class TopicMap:
    """Where one topic's data are in the recording and how to turn them into messages.

    ``shape`` is (rows, cols) for a grid topic or (sensors,) for a sensor topic. Exactly one
    of ``variable``, ``columns`` and ``prefix`` is set. ``time`` is None when the topic uses
    the map's default time base (or the Time field of a timeseries-like struct).
    """

    topic: str
    kind: Kind
    unit: str
    shape: tuple[int, ...]
    variable: str | None = None
    columns: tuple[str, ...] = ()
    prefix: str | None = None
    order: str = "C"
    time_axis: str = "auto"
    time: TimeBase | None = None

    @property
    def size(self) -> int:
        """Values per sample (R*C or S)."""
        size = 1
        for n in self.shape:
            size *= n
        return size

    def to_si(self) -> Unit:
        """Return the conversion of this topic's unit to the contract's unit."""
        return UNITS[self.unit]


@dataclass(frozen=True)
class ImportMap:
    """A whole map: per-topic entries and the default time base (None if not given)."""

    topics: tuple[TopicMap, ...]
    time: TimeBase | None = None


def _check_keys(where: str, entry: object, allowed: frozenset[str]) -> Mapping[str, Any]:
    if not isinstance(entry, Mapping):
        raise MapError(f"{where} must be a mapping, got {type(entry).__name__}")
    unknown = sorted(str(k) for k in entry if k not in allowed)
    if unknown:
        raise MapError(
            f"{where}: unknown key(s) {', '.join(unknown)} (allowed: {', '.join(sorted(allowed))})"
        )
    return entry


def _number(where: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MapError(f"{where} must be a number, got {value!r}")
    return float(value)


def _positive_int(where: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise MapError(f"{where} must be a positive integer, got {value!r}")
    return value


def _name(where: str, value: object) -> str:
    if not isinstance(value, str) or not value:
        raise MapError(f"{where} must be a non-empty string, got {value!r}")
    return value


def parse_time(where: str, entry: object) -> TimeBase:
    """Parse a time base mapping.

    Raises:
        MapError: unknown keys, both or neither of ``variable`` and ``rate``, a bad unit,
            a non-positive rate or a negative start.

    """
    spec = _check_keys(where, entry, _TIME_KEYS)
    if ("variable" in spec) == ("rate" in spec):
        raise MapError(f"{where}: give either 'variable' (a time variable) or 'start' + 'rate'")
    if "variable" in spec:
        if "start" in spec:
            raise MapError(f"{where}: 'start' goes with 'rate', not with a time variable")
        unit = spec.get("unit", "s")
        if unit not in TIME_UNITS:
            raise MapError(
                f"{where}: time unit {unit!r} is not one of {', '.join(TIME_UNITS)}"
            )
        return TimeBase(variable=_name(f"{where}.variable", spec["variable"]),
                        scale=TIME_UNITS[unit])
    if "unit" in spec:
        raise MapError(f"{where}: 'unit' goes with a time variable; start is in s, rate in Hz")
    rate = _number(f"{where}.rate", spec["rate"])
    start = _number(f"{where}.start", spec.get("start", 0.0))
    if not rate > 0 or rate == float("inf"):
        raise MapError(f"{where}.rate must be a positive sample rate in Hz, got {rate!r}")
    if not 0 <= start < float("inf"):
        raise MapError(f"{where}.start must be a time >= 0 s, got {start!r}")
    return TimeBase(start=start, rate=rate)


def _parse_shape(where: str, spec: Mapping[str, Any], kind: Kind) -> tuple[int, ...]:
    if kind == "sensor":
        if "grid" in spec:
            raise MapError(f"{where}: a sensor topic takes 'sensors: S', not 'grid'")
        if "sensors" not in spec:
            raise MapError(f"{where}: missing 'sensors' (the number of temperature sensors)")
        return (_positive_int(f"{where}.sensors", spec["sensors"]),)
    if "sensors" in spec:
        raise MapError(f"{where}: a grid topic takes 'grid: [rows, cols]', not 'sensors'")
    grid = spec.get("grid")
    if grid is None:
        raise MapError(f"{where}: missing 'grid' ([rows, cols])")
    if not isinstance(grid, list) or len(grid) != 2:
        raise MapError(f"{where}.grid must be [rows, cols], got {grid!r}")
    return (_positive_int(f"{where}.grid", grid[0]), _positive_int(f"{where}.grid", grid[1]))


def parse_topic(topic: str, entry: object) -> TopicMap:
    """Parse one topic's entry of the map.

    Raises:
        MapError: the topic cannot be imported, a key is unknown or missing, the unit is not
            in :data:`UNITS` or measures another quantity, or a value has the wrong type.

    """
    if topic not in TOPICS:
        raise MapError(f"topic {topic!r} cannot be imported; importable: {', '.join(TOPICS)}")
    where = f"topics.{topic}"
    spec = _check_keys(where, entry, _TOPIC_KEYS)
    kind, quantity = TOPICS[topic]
    sources = [k for k in ("variable", "columns", "prefix") if k in spec]
    if len(sources) != 1:
        raise MapError(f"{where}: give exactly one of 'variable', 'columns', 'prefix'")
    unit = spec.get("unit")
    if unit is None:
        raise MapError(f"{where}: missing 'unit'")
    if unit not in UNITS:
        raise MapError(f"{where}: unit {unit!r} is not one of {', '.join(UNITS)}")
    if UNITS[unit].quantity != quantity:
        raise MapError(f"{where}: unit {unit!r} is a {UNITS[unit].quantity}, {topic} needs a "
                       f"{quantity}")
    columns: tuple[str, ...] = ()
    if "columns" in spec:
        raw = spec["columns"]
        if not isinstance(raw, list) or not raw:
            raise MapError(f"{where}.columns must be a non-empty list of names")
        columns = tuple(_name(f"{where}.columns", c) for c in raw)
    order = spec.get("order", "C")
    if order not in ORDERS:
        raise MapError(f"{where}.order must be C (row-major) or F (column-major), got {order!r}")
    time_axis = spec.get("time_axis", "auto")
    if time_axis not in TIME_AXES:
        raise MapError(f"{where}.time_axis must be one of {', '.join(TIME_AXES)}, "
                       f"got {time_axis!r}")
    return TopicMap(
        topic=topic,
        kind=kind,
        unit=unit,
        shape=_parse_shape(where, spec, kind),
        variable=_name(f"{where}.variable", spec["variable"]) if "variable" in spec else None,
        columns=columns,
        prefix=_name(f"{where}.prefix", spec["prefix"]) if "prefix" in spec else None,
        order=order,
        time_axis=time_axis,
        time=parse_time(f"{where}.time", spec["time"]) if "time" in spec else None,
    )


def parse_map(document: object) -> ImportMap:
    """Validate a loaded YAML document and return the map.

    Raises:
        MapError: anything in it is invalid (see :func:`parse_topic`, :func:`parse_time`).

    """
    spec = _check_keys("map", document, _MAP_KEYS)
    topics = spec.get("topics")
    if not isinstance(topics, Mapping) or not topics:
        raise MapError("map: 'topics' must map at least one topic to its data")
    default = parse_time("time", spec["time"]) if "time" in spec else None
    return ImportMap(tuple(parse_topic(str(t), e) for t, e in topics.items()), default)


def load_map(path: str | Path) -> ImportMap:
    """Read and validate a map file.

    Raises:
        MapError: the file cannot be read, is not YAML, or is not a valid map.

    """
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise MapError(f"cannot read map {path}: {getattr(err, 'strerror', None) or err}") from None
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise MapError(f"map {path} is not valid YAML{at}") from None
    try:
        return parse_map(document)
    except MapError as err:
        raise MapError(f"map {path}: {err}") from None
