"""Build ``diagnostic_msgs`` messages from plain Python values."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from enum import IntEnum

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue


class Level(IntEnum):
    """Diagnostic levels of ``diagnostic_msgs/msg/DiagnosticStatus``."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


def make_status(
    name: str,
    level: Level,
    message: str,
    values: Mapping[str, object] | None = None,
    hardware_id: str = "",
) -> DiagnosticStatus:
    """Return one status; ``values`` become key/value pairs (floats with 6 significant digits)."""
    pairs = [
        KeyValue(key=str(k), value=f"{v:.6g}" if isinstance(v, float) else str(v))
        for k, v in (values or {}).items()
    ]
    return DiagnosticStatus(
        level=bytes([int(level)]), name=name, message=message, hardware_id=hardware_id, values=pairs
    )


def make_array(stamp: Time, statuses: Iterable[DiagnosticStatus]) -> DiagnosticArray:
    """Return a ``DiagnosticArray`` stamped ``stamp`` holding ``statuses``."""
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = list(statuses)
    return msg


def level_of(status: DiagnosticStatus) -> Level:
    """Return the level of a received status as a :class:`Level`."""
    raw = status.level
    return Level(raw[0] if isinstance(raw, bytes | bytearray) else int(raw))
