"""``ros2 run es_recordings record -o BAG [--storage mcap|sqlite3] [--all-dm] TOPIC...``.

Records topics into a rosbag2 bag (see :mod:`es_msgs_py.bag`). Messages are taken as
serialized bytes (no deserialization) and stamped with the node's clock at reception, so the
bag runs on sim time when ``use_sim_time`` is set (``--ros-args -p use_sim_time:=true``).
Subscriptions use the contract QoS of each topic with a deeper queue, so that a short stall
(a chunk write, a garbage collection) loses nothing at kHz rates. The bag is flushed every
``--flush-interval`` seconds, so even a killed recorder leaves a bag readable up to its last
flush; SIGINT/SIGTERM close it cleanly (after taking what is still on its way, see below).
Counts of received and written messages per topic are published on /diagnostics every
``--report-period`` seconds (default 1) and logged at exit, with the messages the recorder
missed: from each message's publication sequence number (the publisher's count, 1 for its
first message), what was published before the recorder joined and what fell into gaps
since. That is known
for topics with one publisher (every /dm topic); elsewhere it is reported as unknown. A hole
at the end of a run shows in no sequence number: nodes announce on /diagnostics how many
messages they published per topic (``"<node>: published"``, the plant does), and the
recorder counts as "not received" the missed ones plus what was announced beyond the newest
sequence number it received, per topic, in its reports and in its closing log (after a last
report), so that a hole in a bag is never silent. At SIGINT/SIGTERM the recorder first takes
what is already on its way (:class:`es_node_runtime.node_main.Draining`): until no message has
come for :data:`QUIET_S` and every announced message has arrived, at most
:data:`es_node_runtime.node_main.DRAIN_LIMIT` seconds; its closing log names what it still
waited for.
``record: ready`` on /diagnostics says "not ready" until every recorded /dm topic has matched
a publisher (a lockstep plant can wait for it: nothing of the run is then missed).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NoReturn

from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.event_handler import QoSMessageLostInfo, SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription
from rclpy.validate_full_topic_name import validate_full_topic_name
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from es_msgs_py import topics
from es_msgs_py.bag import STORAGES, BagError, BagWriter
from es_msgs_py.diagnostics import (
    RECORDER_NODE,
    Level,
    announced_counts,
    make_array,
    make_status,
    readiness_status,
    unmatched,
)
from es_node_runtime.node_main import DRAIN_LIMIT, run_node, summary_line

NODE_NAME = RECORDER_NODE
#: Topics taken by ``--all-dm``.
ALL_DM_TOPICS = (*topics.DM_TOPICS, topics.DIAGNOSTICS)


@dataclass(frozen=True)
class Options:
    """What to record and where."""

    output: str
    storage: str
    topics: tuple[str, ...]
    flush_interval: float
    queue_depth: int
    #: seconds between the counts on /diagnostics (a flow-controlled source paces on them)
    report_period: float = 1.0


#: Wall seconds without a new message after which a stopping recorder takes its queues for
#: empty: what DDS has already received is taken within milliseconds.
QUIET_S = 0.2

#: Topics with exactly one publisher by contract: their publication sequence numbers count
#: every message published, so a missed message shows.
SINGLE_PUBLISHER_TOPICS = frozenset(topics.DM_TOPICS)


@dataclass
class TopicCount:
    """Messages of one topic received from DDS, written to the bag, and reported lost.

    ``lost`` is what the middleware reports as lost before reception (its message-lost
    event); it stays 0 where the middleware does not report losses. ``missed`` counts the
    messages the publisher published but this recorder never received (before it joined:
    ``first_sequence - 1``; later: gaps in the sequence numbers); ``None`` when unknown
    (several publishers, or a middleware without publication sequence numbers).
    ``announced`` is the publisher's own count of what it published (0: none announced).
    """

    type_name: str
    received: int = 0
    written: int = 0
    lost: int = 0
    missed: int | None = None
    first_sequence: int | None = None
    last_sequence: int = 0
    announced: int = 0

    def note_sequence(self, sequence: int) -> None:
        """Account for a message with publication sequence number ``sequence`` (0: none)."""
        if sequence <= 0:
            return
        if self.first_sequence is None:
            self.first_sequence = sequence
            self.missed = sequence - 1
        elif sequence > self.last_sequence + 1 and self.missed is not None:
            self.missed += sequence - self.last_sequence - 1
        self.last_sequence = max(self.last_sequence, sequence)

    def not_received(self) -> int | None:
        """Return the messages known published and not received, ``None`` when unknown.

        The missed ones, plus the announced ones beyond the newest sequence number received
        (all of them when nothing was received): what a hole at the end of a run leaves.
        """
        if self.first_sequence is None:
            return self.announced or self.missed
        return (self.missed or 0) + max(self.announced - self.last_sequence, 0)

    def not_received_text(self) -> str:
        """Return :meth:`not_received`, or ``unknown`` (never a silent 0)."""
        count = self.not_received()
        return "unknown" if count is None else str(count)

    def missed_text(self) -> str:
        """Return the missed count, or ``unknown`` (never a silent 0)."""
        return "unknown" if self.missed is None else str(self.missed)


def _bag_time(duration: Duration) -> QosTime:
    sec, nsec = divmod(int(duration.nanoseconds), 1_000_000_000)
    return QosTime(sec=sec, nsec=nsec)


def offered_qos(profile: QoSProfile) -> Qos:
    """Return ``profile`` (a publisher's QoS) as a bag's ``offered_qos_profiles`` entry."""
    return Qos(
        QosHistory(int(profile.history)),
        int(profile.depth),
        QosReliability(int(profile.reliability)),
        QosDurability(int(profile.durability)),
        _bag_time(profile.deadline),
        _bag_time(profile.lifespan),
        QosLiveliness(int(profile.liveliness)),
        _bag_time(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


class _OneLineParser(argparse.ArgumentParser):
    """Argument errors are one line on stderr and exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def parse_args(argv: Sequence[str]) -> Options:
    """Parse the command line (without ROS arguments); exit 2 with one line when invalid."""
    parser = _OneLineParser(
        prog=NODE_NAME,
        description="Record topics of the es_dm contract into a rosbag2 bag.",
    )
    parser.add_argument("topics", nargs="*", metavar="TOPIC", help="topics to record")
    parser.add_argument("-o", "--output", required=True, help="bag directory to create")
    parser.add_argument("--storage", choices=STORAGES, default="mcap", help="storage format")
    parser.add_argument("--all-dm", action="store_true", help=f"record {', '.join(ALL_DM_TOPICS)}")
    parser.add_argument(
        "--flush-interval", type=float, default=0.5, help="seconds between flushes to disk"
    )
    parser.add_argument(
        "--queue-depth", type=int, default=1000, help="subscription queue depth per topic"
    )
    parser.add_argument(
        "--report-period", type=float, default=1.0,
        help="seconds between the counts on /diagnostics (also sent on a level change)",
    )
    ns = parser.parse_args(list(argv))
    names = [*ALL_DM_TOPICS] if ns.all_dm else []
    for name in ns.topics:
        full = name if name.startswith("/") else f"/{name}"
        try:
            validate_full_topic_name(full)
        except Exception as err:  # rclpy raises its own InvalidTopicNameException
            parser.error(f"invalid topic name {name!r}: {str(err).splitlines()[0]}")
        names.append(full)
    if not names:
        parser.error("give at least one TOPIC or --all-dm")
    if not 0.0 < ns.flush_interval <= 3600.0:
        parser.error(f"--flush-interval must be in (0, 3600] s, got {ns.flush_interval}")
    if ns.queue_depth < 1:
        parser.error(f"--queue-depth must be >= 1, got {ns.queue_depth}")
    if not 0.01 <= ns.report_period <= 3600.0:
        parser.error(f"--report-period must be in [0.01, 3600] s, got {ns.report_period}")
    return Options(
        ns.output, ns.storage, tuple(dict.fromkeys(names)), ns.flush_interval, ns.queue_depth,
        ns.report_period,
    )


class Recorder(Node):
    """Subscribe to topics as raw bytes and write each message to a bag."""

    def __init__(self, options: Options) -> None:
        """Create the bag (``ValueError``/``BagError`` if it exists) and start subscribing."""
        super().__init__(NODE_NAME)
        self._options = options
        self._bag = BagWriter(options.output, options.storage)
        self._counts: dict[str, TopicCount] = {}
        self._recorded: dict[str, Subscription] = {}  # by topic; Node owns `_subscriptions`
        self._pending = [t for t in options.topics if t not in topics.TOPIC_TYPES]
        self._write_failed = False
        self._last_arrival = time.monotonic()
        for topic in options.topics:
            if topic in topics.TOPIC_TYPES:
                self._subscribe(topic, topics.TOPIC_TYPES[topic])
        self._diagnostics = self.create_publisher(
            topics.message_class(topics.DIAGNOSTIC_ARRAY),
            topics.DIAGNOSTICS,
            topics.qos_for(topics.DIAGNOSTICS),
        )
        # Steady-clock timers: flushing must go on when sim time stands still.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(options.flush_interval, self._flush, clock=steady)
        self.create_timer(options.report_period, self._publish_diagnostics, clock=steady)
        if self._pending:
            self.create_timer(0.2, self._discover, clock=steady)
        self._waiting_for = self._unmatched()
        self._ready_timer = self.create_timer(0.05, self._check_ready, clock=steady)
        self.get_logger().info(
            f"recording {', '.join(options.topics)} to {options.output} ({options.storage})"
        )

    def _subscribe(
        self, topic: str, type_name: str, offered: Sequence[QoSProfile] = ()
    ) -> None:
        """Record ``topic``; the bag says it was offered ``offered`` (default: the contract's).

        Raises:
            BagError: the bag cannot register the topic (unknown type, another type).

        """
        contract = topics.qos_for(topic)
        qos = QoSProfile(
            history=contract.history,
            depth=max(contract.depth, self._options.queue_depth),
            reliability=contract.reliability,
            durability=contract.durability,
        )
        # what the publishers offer, as rosbag2 writes it (a contract topic: the contract's
        # QoS, which every es_dm endpoint uses; a discovered one: its publishers' own)
        self._bag.add_topic(topic, type_name, [offered_qos(q) for q in offered or (contract,)])
        count = self._counts[topic] = TopicCount(type_name)

        counts_sequence = topic in SINGLE_PUBLISHER_TOPICS
        reads_announcements = type_name == topics.DIAGNOSTIC_ARRAY

        def on_message(data: bytes, info: Mapping[str, int]) -> None:
            self._last_arrival = time.monotonic()
            count.received += 1
            if counts_sequence:
                count.note_sequence(int(info.get("publication_sequence_number", 0)))
            if reads_announcements:
                self._note_announcements(data)
            try:
                self._bag.write(topic, self.get_clock().now().nanoseconds, data, type_name)
            except (BagError, OSError) as err:
                if not self._write_failed:
                    self._write_failed = True
                    self.get_logger().error(f"cannot write to {self._options.output}: {err}")
                    self._publish_diagnostics()  # the level just changed: say so now
                return
            count.written += 1

        def on_lost(status: QoSMessageLostInfo) -> None:
            count.lost = int(status.total_count)

        self._recorded[topic] = self.create_subscription(
            topics.message_class(type_name),
            topic,
            on_message,  # type: ignore[arg-type]  # rclpy passes the message info to 2 args
            qos,
            raw=True,
            event_callbacks=SubscriptionEventCallbacks(message_lost=on_lost),
        )

    def _note_announcements(self, data: bytes) -> None:
        """Take the published counts that nodes announce on /diagnostics (few per second)."""
        message = deserialize_message(data, topics.message_class(topics.DIAGNOSTIC_ARRAY))
        for topic, published in announced_counts(message).items():
            count = self._counts.get(topic)
            if count is not None and topic in SINGLE_PUBLISHER_TOPICS:
                count.announced = published

    def awaited(self) -> dict[str, int]:
        """Return, per topic, the announced messages beyond the newest one received."""
        behind = {t: c.announced - c.last_sequence for t, c in self._counts.items()}
        return {t: n for t, n in behind.items() if n > 0}

    def settled(self) -> bool:
        """Whether a stop may close the bag: queues quiet, every announced message here."""
        return time.monotonic() - self._last_arrival >= QUIET_S and not self.awaited()

    def _unmatched(self) -> list[str]:
        """Return the recorded /dm topics without a matched publisher, and undiscovered ones."""
        dm = [s for t, s in self._recorded.items() if t in SINGLE_PUBLISHER_TOPICS]
        return [*unmatched(dm), *self._pending]

    def _check_ready(self) -> None:
        """Follow the recorded topics' matching until ready; say so on /diagnostics at once."""
        waiting = self._unmatched()
        if waiting != self._waiting_for:
            self._waiting_for = waiting
            self._publish_diagnostics()
        if not waiting:
            self._ready_timer.cancel()

    def _flush(self) -> None:
        try:
            self._bag.flush()
        except OSError as err:  # a full disk must not end the recording of what still fits
            self.get_logger().error(f"cannot flush {self._options.output}: {err}", once=True)

    def _discover(self) -> None:
        """Subscribe to non-contract topics once their type shows up on the graph."""
        known = dict(self.get_topic_names_and_types())
        for topic in list(self._pending):
            types = known.get(topic)
            if not types:
                continue
            self._pending.remove(topic)
            offered = [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
            try:
                self._subscribe(topic, types[0], offered)
            except (BagError, ValueError) as err:
                self.get_logger().error(f"cannot record {topic}: {err}")

    def _publish_diagnostics(self) -> None:
        values: dict[str, object] = {"bag": self._options.output}
        for topic, count in self._counts.items():
            values[f"{topic} received"] = count.received
            values[f"{topic} written"] = count.written
            values[f"{topic} lost"] = count.lost
            values[f"{topic} missed"] = count.missed_text()
            values[f"{topic} not received"] = count.not_received_text()
            # publishers matched: what a peer waits for before it publishes (readiness)
            values[f"{topic} publishers"] = self._recorded[topic].get_publisher_count()
        for topic in self._pending:
            values[f"{topic} received"] = "waiting for publisher"
        unwritten = sum(c.received - c.written for c in self._counts.values())
        lost = sum(c.lost for c in self._counts.values())
        missing = {t: n for t, c in self._counts.items() if (n := c.not_received())}
        if unwritten:
            level, text = Level.ERROR, f"{unwritten} received messages not written"
        elif missing:
            level = Level.WARN
            text = "not received " + ", ".join(f"{n} on {t}" for t, n in missing.items()) + (
                " (published before the recorder joined, lost, or still on the way)"
            )
        elif lost:
            level, text = Level.WARN, f"middleware lost {lost} messages before reception"
        else:
            level, text = Level.OK, "recording"
        self._diagnostics.publish(
            make_array(
                self.get_clock().now().to_msg(),
                [
                    readiness_status(NODE_NAME, self._waiting_for),
                    make_status(f"{NODE_NAME}: bag", level, text, values),
                ],
            )
        )

    def close(self) -> None:
        """Report the counts a last time, finish the bag and print them per topic.

        The closing lines (:func:`summary_line`) name, per topic, what the recorder knows it
        has not received at this moment (:meth:`TopicCount.not_received`).
        """
        self._publish_diagnostics()
        self._bag.close()
        awaited = self.awaited()
        if awaited:
            summary_line(
                NODE_NAME,
                "stopped while still waiting for "
                + ", ".join(f"{n} on {t}" for t, n in awaited.items())
                + f" (announced by their publishers, not here {DRAIN_LIMIT:g} s after the stop)",
            )
        for topic, count in self._counts.items():
            summary_line(
                NODE_NAME,
                f"{topic}: received {count.received}, written {count.written}, "
                f"lost before reception {count.lost}, missed {count.missed_text()}, "
                f"not received {count.not_received_text()}",
            )
        summary_line(NODE_NAME, f"bag closed: {self._options.output}")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the recorder until SIGINT/SIGTERM; return the process exit code."""
    from rclpy.utilities import remove_ros_args

    args = list(sys.argv if argv is None else argv)
    options = parse_args(remove_ros_args(args)[1:])
    return run_node(lambda: Recorder(options), args)


if __name__ == "__main__":
    sys.exit(main())
