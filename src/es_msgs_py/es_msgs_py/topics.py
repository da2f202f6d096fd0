"""Topic names, message types and QoS of the es_dm contract."""

from __future__ import annotations

import fcntl
import importlib
import os
import tempfile
from pathlib import Path
from typing import IO, Final

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from es_msgs_py.errors import UnknownMessageTypeError
from es_msgs_py.topic_names import (
    CLOCK,
    COMMAND,
    DIAGNOSTICS,
    DISPLACEMENT,
    DM_DEPTH,
    HEAT_LOAD,
    RESONANCE,
    SETPOINT,
    TEMPERATURE,
    TEMPERATURE_RAW,
)

#: Highest ROS domain whose DDS ports (for the first 50 participants of a host) stay below
#: Linux's ephemeral range (32768+): in that range any socket of the machine can hold a port
#: a participant needs, and discovery then fails now and then (ROS 2 docs, "About Domain ID").
MAX_SAFE_DOMAIN_ID: Final = 101


def process_domain_id(pid: int | None = None) -> int:
    """Return a ROS domain in 1..MAX_SAFE_DOMAIN_ID picked from ``pid`` (default: this one).

    Tests, benchmarks and the demo isolate their traffic with it.
    """
    return 1 + (os.getpid() if pid is None else pid) % MAX_SAFE_DOMAIN_ID


#: Lock files of the domains this process holds (kept open: a lock lives with its file).
_HELD_DOMAINS: list[IO[bytes]] = []


def reserve_domain_id(lock_dir: Path | None = None) -> int:
    """Return a ROS domain in 1..MAX_SAFE_DOMAIN_ID that no other es_dm process here holds.

    Two processes whose PIDs pick the same domain (:func:`process_domain_id`) would see each
    other's nodes (on a shared machine or CI runner, a test run of another checkout can
    publish into this one's graph). This one starts at the PID's domain and takes the first
    whose lock file ``<lock_dir>/<domain>.lock`` (default: ``es_dm_domains`` in the temporary
    directory) it can lock; the lock is held until the process exits. When every domain is
    held it falls back to the PID's.
    """
    folder = lock_dir or Path(tempfile.gettempdir()) / "es_dm_domains"
    first = process_domain_id()
    try:
        folder.mkdir(mode=0o777, exist_ok=True)
    except OSError:
        return first
    for offset in range(MAX_SAFE_DOMAIN_ID):
        domain = 1 + (first - 1 + offset) % MAX_SAFE_DOMAIN_ID
        try:
            handle = (folder / f"{domain}.lock").open("ab")
        except OSError:
            continue
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        _HELD_DOMAINS.append(handle)
        return domain
    return first


#: Every /dm topic of the contract, in data-flow order.
DM_TOPICS: Final = (HEAT_LOAD, TEMPERATURE_RAW, TEMPERATURE, SETPOINT, COMMAND, DISPLACEMENT)
#: /dm topics of optional features, recorded only when asked for (the self-sensing input).
OPTIONAL_DM_TOPICS: Final = (RESONANCE,)

FLOAT64_MULTI_ARRAY: Final = "std_msgs/msg/Float64MultiArray"
DIAGNOSTIC_ARRAY: Final = "diagnostic_msgs/msg/DiagnosticArray"
CLOCK_TYPE: Final = "rosgraph_msgs/msg/Clock"

#: ROS 2 type name of each contract topic.
TOPIC_TYPES: Final[dict[str, str]] = {
    **dict.fromkeys(DM_TOPICS, FLOAT64_MULTI_ARRAY),
    **dict.fromkeys(OPTIONAL_DM_TOPICS, FLOAT64_MULTI_ARRAY),
    DIAGNOSTICS: DIAGNOSTIC_ARRAY,
    CLOCK: CLOCK_TYPE,
}

#: QoS of every /dm topic, publishers and subscriptions alike: reliable, volatile, keep last
#: DM_DEPTH (the contract's keep-last-10 exception, documented in docs/architecture.md).
#: History depth is not part of QoS matching, so endpoints of other nodes with the
#: contract's depth of 10 still match.
DM_QOS: Final = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=DM_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)


#: QoS of /diagnostics, as diagnostic_updater uses it.
DIAGNOSTICS_QOS: Final = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

#: QoS of /clock, as rclpy's time source subscribes to it.
CLOCK_QOS: Final = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)


def qos_for(topic: str) -> QoSProfile:
    """Return the contract QoS for ``topic`` (the /dm QoS for any topic not listed)."""
    if topic == CLOCK:
        return CLOCK_QOS
    if topic == DIAGNOSTICS:
        return DIAGNOSTICS_QOS
    return DM_QOS


def message_class(type_name: str) -> type:
    """Return the rclpy message class for a ROS 2 type name such as ``std_msgs/msg/Header``.

    Raises:
        UnknownMessageTypeError: the name is not of the form ``pkg/msg/Name`` or cannot be
            imported.

    """
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] != "msg" or not all(p.isidentifier() for p in parts):
        raise UnknownMessageTypeError(f"not a ROS 2 message type name: {type_name!r}")
    try:
        module = importlib.import_module(f"{parts[0]}.msg")
        cls = getattr(module, parts[2])
    except (AttributeError, ImportError) as err:
        raise UnknownMessageTypeError(f"unknown message type {type_name!r}: {err}") from None
    if not isinstance(cls, type):
        raise UnknownMessageTypeError(f"unknown message type {type_name!r}")
    return cls
