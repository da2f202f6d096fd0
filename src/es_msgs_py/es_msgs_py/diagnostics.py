"""Build ``diagnostic_msgs`` messages from plain Python values; readiness statuses."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from enum import IntEnum
from typing import Protocol

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


#: Aspect of a node's readiness status: ``"<node>: ready"``, OK once the node has the inputs
#: it needs, WARN ("not ready: ...") until then. A lockstep plant waits for it before its
#: first step (its ``wait_ready`` parameter).
READY_ASPECT = "ready"


class _Matched(Protocol):
    """A subscription that knows how many publishers it matched (rclpy ``Subscription``)."""

    @property
    def topic_name(self) -> str:
        """The subscription's topic."""

    def get_publisher_count(self) -> int:
        """Return how many publishers the subscription matched."""


def unmatched(subscriptions: Iterable[_Matched]) -> list[str]:
    """Return the topics of ``subscriptions`` that have matched no publisher yet."""
    return [s.topic_name for s in subscriptions if s.get_publisher_count() == 0]


class _Publishing(Protocol):
    """A publisher that knows how many subscriptions it matched (rclpy ``Publisher``)."""

    @property
    def topic_name(self) -> str:
        """The publisher's topic."""

    def get_subscription_count(self) -> int:
        """Return how many subscriptions the publisher matched."""


def unreached(publisher: _Publishing, wanted: int) -> list[str]:
    """Describe ``publisher`` if it has matched fewer than ``wanted`` subscriptions, else ``[]``.

    Matching is one-sided in DDS: a subscription that has matched a publisher (what the
    subscriber's readiness sees) gets nothing the publisher sends before the publisher has
    matched it in turn, so a node whose first message must reach every peer (a recorder's
    bag) waits for its own publisher's count.
    """
    have = publisher.get_subscription_count()
    if have >= wanted:
        return []
    return [f"{publisher.topic_name} subscribers ({have} of {wanted} matched)"]


def readiness_status(node: str, waiting_for: Sequence[str]) -> DiagnosticStatus:
    """Return the ``"<node>: ready"`` status: OK, or WARN naming what the node waits for."""
    if not waiting_for:
        return make_status(f"{node}: {READY_ASPECT}", Level.OK, "ready")
    return make_status(
        f"{node}: {READY_ASPECT}",
        Level.WARN,
        f"not ready: waiting for {', '.join(waiting_for)}",
    )


def ready_nodes(msg: DiagnosticArray) -> dict[str, bool]:
    """Return, per node that reports readiness in ``msg``, whether it says it is ready.

    Node names are the part of ``"<node>: ready"`` before the colon (no namespace).
    """
    out = {}
    suffix = f": {READY_ASPECT}"
    for status in msg.status:
        if status.name.endswith(suffix):
            out[status.name[: -len(suffix)]] = level_of(status) is Level.OK
    return out


#: Aspect under which a node announces how many messages it has published per topic
#: (``"<node>: published"``, one value per topic): a recorder learns from it how many it
#: has not received, the end of a run included, which sequence numbers alone cannot show.
PUBLISHED_ASPECT = "published"
#: Node name of the recorder (``es_recordings record``).
RECORDER_NODE = "record"
#: Status in which the recorder reports its counts; ``"<topic> received"`` among its values.
RECORDER_BAG_STATUS = f"{RECORDER_NODE}: bag"
#: Suffix of the recorder's per-topic received count in :data:`RECORDER_BAG_STATUS`.
RECEIVED_SUFFIX = " received"


def published_status(node: str, counts: Mapping[str, int]) -> DiagnosticStatus:
    """Return the ``"<node>: published"`` status: messages published so far, per topic."""
    return make_status(
        f"{node}: {PUBLISHED_ASPECT}", Level.OK, "messages published per topic", counts
    )


def announced_counts(msg: DiagnosticArray) -> dict[str, int]:
    """Return ``{topic: count}`` from every ``"<node>: published"`` status in ``msg``."""
    suffix = f": {PUBLISHED_ASPECT}"
    return {
        kv.key: int(kv.value)
        for status in msg.status
        if status.name.endswith(suffix)
        for kv in status.values
        if kv.value.isdigit()
    }


def recorder_received(msg: DiagnosticArray) -> dict[str, int]:
    """Return ``{topic: received}`` from the recorder's report in ``msg`` (``{}`` if none)."""
    return {
        kv.key[: -len(RECEIVED_SUFFIX)]: int(kv.value)
        for status in msg.status
        if status.name == RECORDER_BAG_STATUS
        for kv in status.values
        if kv.key.endswith(RECEIVED_SUFFIX) and kv.value.isdigit()
    }


def not_yet_received(published: Mapping[str, int], received: Mapping[str, int]) -> dict[str, int]:
    """Return ``{topic: messages}`` published but not received, over the topics in both."""
    behind = {t: n - received[t] for t, n in published.items() if t in received}
    return {t: n for t, n in behind.items() if n > 0}
