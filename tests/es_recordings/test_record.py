"""Contract messages over real DDS, and the `record` executable as a process."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray
from support.ros import (
    READY_TIMEOUT,
    NodeProcess,
    executable,
    poll_until,
    wait_matched,
    wait_until,
)
from support.ros import test_node as ros_node

from es_msgs_py.arrays import grid_to_msg, msg_to_grid, msg_to_sensors, sensors_to_msg
from es_msgs_py.bag import BagError, decode_float64_multi_arrays, read_bag
from es_msgs_py.diagnostics import make_array, published_status
from es_msgs_py.topics import (
    CLOCK,
    COMMAND,
    DIAGNOSTICS,
    DIAGNOSTICS_QOS,
    DM_DEPTH,
    DM_QOS,
    SETPOINT,
    TEMPERATURE_RAW,
    qos_for,
)
from es_recordings.record import TopicCount

pytestmark = pytest.mark.dds

# The test's publishers keep every sample until it is acknowledged, so that a lost message
# can only be the recorder's fault (the contract's keep-last-10 would let a slow test
# machine overwrite unacknowledged samples in the publisher itself).
PUBLISHER_QOS = QoSProfile(
    history=DM_QOS.history, depth=5000, reliability=DM_QOS.reliability, durability=DM_QOS.durability
)


def test_dds_round_trip_in_process() -> None:
    grids = [np.arange(12.0).reshape(3, 4) * k for k in range(5)]
    sensors = np.array([40.0, 41.5, np.nan])
    received: list[Float64MultiArray] = []
    raw: list[bytes] = []
    with ros_node("es_round_trip") as node:
        node.create_subscription(Float64MultiArray, COMMAND, received.append, qos_for(COMMAND))
        node.create_subscription(Float64MultiArray, COMMAND, raw.append, qos_for(COMMAND), raw=True)
        got_sensors: list[Float64MultiArray] = []
        node.create_subscription(
            Float64MultiArray, TEMPERATURE_RAW, got_sensors.append, qos_for(TEMPERATURE_RAW)
        )
        command = node.create_publisher(Float64MultiArray, COMMAND, PUBLISHER_QOS)
        temperature = node.create_publisher(Float64MultiArray, TEMPERATURE_RAW, PUBLISHER_QOS)
        wait_matched(node, [command], count=2)
        wait_matched(node, [temperature])
        for grid in grids:
            command.publish(grid_to_msg(grid))
        temperature.publish(sensors_to_msg(sensors))
        wait_until(
            node,
            lambda: len(received) == len(raw) == 5 and len(got_sensors) == 1,
            f"5 commands twice and 1 sensor message (got {len(received)}, {len(raw)}, "
            f"{len(got_sensors)})",
        )
    for msg, grid in zip(received, grids, strict=True):
        np.testing.assert_array_equal(msg_to_grid(msg, (3, 4)), grid)
    np.testing.assert_array_equal(msg_to_sensors(got_sensors[0], 3), sensors)
    # The bag decoder reads what DDS delivers (rclpy's CDR, padding and all).
    np.testing.assert_array_equal(decode_float64_multi_arrays(COMMAND, raw), np.stack(grids))


def _written_counts(msg: DiagnosticArray) -> dict[str, int]:
    counts = {}
    for status in msg.status:
        if status.name == "record: bag":
            for pair in status.values:
                if pair.key.endswith(" written"):
                    counts[pair.key.removesuffix(" written")] = int(pair.value)
    return counts


def _record_and_publish(
    node: Node, recorder: NodeProcess, topics: dict[str, list[Float64MultiArray]]
) -> None:
    """Publish every message of ``topics`` and wait until the recorder reports them written."""
    latest: dict[str, int] = {}
    reports = node.create_subscription(
        DiagnosticArray,
        DIAGNOSTICS,
        lambda msg: latest.update(_written_counts(msg)),
        qos_for(DIAGNOSTICS),
    )
    publishers = {t: node.create_publisher(Float64MultiArray, t, PUBLISHER_QOS) for t in topics}
    wait_matched(node, [reports, *publishers.values()], processes=[recorder])
    for i in range(max(len(m) for m in topics.values())):
        for topic, msgs in topics.items():
            if i < len(msgs):
                publishers[topic].publish(msgs[i])
        time.sleep(0.001)  # the scenario: about 1 kHz
    _wait_written(node, recorder, latest, {t: len(m) for t, m in topics.items()})


def _wait_written(
    node: Node, recorder: NodeProcess, latest: dict[str, int], expected: dict[str, int]
) -> None:
    """Spin until the recorder's reports (``latest``, kept up to date) show ``expected``."""
    wait_until(
        node,
        lambda: all(latest.get(t) == n for t, n in expected.items()),
        f"recorder report of {expected} written (last report {latest})",
        processes=[recorder],
    )


def test_recorder_writes_every_message_and_closes_on_sigint(tmp_path: Path) -> None:
    grids = np.random.default_rng(1).normal(size=(300, 4, 4))
    sensors = np.random.default_rng(2).normal(size=(30, 5))
    bag = tmp_path / "bag"
    recorder = NodeProcess(
        "es_recordings", "record", ["-o", str(bag), COMMAND, TEMPERATURE_RAW, DIAGNOSTICS]
    )
    try:
        with ros_node("es_record_test") as node:
            _record_and_publish(
                node,
                recorder,
                {
                    COMMAND: [grid_to_msg(g) for g in grids],
                    TEMPERATURE_RAW: [sensors_to_msg(s) for s in sensors],
                },
            )
    finally:
        code = recorder.stop(signal.SIGINT)
    assert code == 0, recorder.output()
    assert "/dm/command: received 300, written 300, lost before reception 0" in recorder.output()
    assert (bag / "metadata.yaml").is_file()
    series = read_bag(bag)
    got = series[COMMAND].values
    assert got is not None
    np.testing.assert_array_equal(got, grids)
    got = series[TEMPERATURE_RAW].values
    assert got is not None
    np.testing.assert_array_equal(got, sensors)
    assert np.all(np.diff(series[COMMAND].times) >= 0)
    assert abs(series[COMMAND].times[0] - time.time()) < 120  # wall-clock stamps
    assert len(series[DIAGNOSTICS]) >= 1  # its own counts, at least
    # the bag's metadata says what the publishers offer: /dm keep last DM_DEPTH, not 10
    offered = _offered_qos(bag)
    assert offered[COMMAND] == offered[TEMPERATURE_RAW] == [("keep_last", DM_DEPTH, "reliable")]
    assert offered[DIAGNOSTICS] == [("keep_last", DIAGNOSTICS_QOS.depth, "reliable")]


def test_a_stopping_recorder_takes_what_is_on_its_way_and_names_what_never_came(
    tmp_path: Path,
) -> None:
    # Forced ordering: the recorder is stopped (SIGSTOP) while messages are sent to it, gets
    # SIGINT while stopped and continues with the messages still in its DDS queues. Taken
    # at once, the stop lost them; now it takes them first. The publisher announces 3 more
    # than it sends: the recorder waits for those, bounded, and names them at its close.
    sent, never_sent = 200, 3
    bag = tmp_path / "bag"
    recorder = NodeProcess("es_recordings", "record", ["-o", str(bag), SETPOINT, DIAGNOSTICS])
    stopped = False
    try:
        with ros_node("es_record_drain_test") as node:
            data = node.create_publisher(Float64MultiArray, SETPOINT, PUBLISHER_QOS)
            announcer = node.create_publisher(DiagnosticArray, DIAGNOSTICS, DIAGNOSTICS_QOS)
            first = grid_to_msg(np.zeros((2, 2)))
            _acknowledged(data, first, recorder)
            _acknowledged(announcer, DiagnosticArray(), recorder)
            os.kill(recorder.pid, signal.SIGSTOP)
            stopped = True
            for value in range(sent - 1):
                data.publish(grid_to_msg(np.full((2, 2), float(value))))
            announced = published_status("es_record_drain_test", {SETPOINT: sent + never_sent})
            announcer.publish(make_array(Time(), [announced]))
            os.kill(recorder.pid, signal.SIGINT)  # handled only once it runs again
            os.kill(recorder.pid, signal.SIGCONT)
            stopped = False
            code = recorder.process.wait(READY_TIMEOUT)  # the publisher lives meanwhile
    finally:
        if stopped:
            os.kill(recorder.pid, signal.SIGCONT)
        recorder.stop()
    output = recorder.output()
    assert code == 0, output
    assert len(read_bag(bag, [SETPOINT])[SETPOINT]) == sent, output
    assert (f"{SETPOINT}: received {sent}, written {sent}, lost before reception 0, "
            f"missed 0, not received {never_sent}") in output
    assert f"stopped while still waiting for {never_sent} on {SETPOINT}" in output


def _acknowledged(publisher: Publisher, msg: object, recorder: NodeProcess) -> None:
    """Publish ``msg`` once the recorder has matched, and wait until it acknowledged it."""
    poll_until(lambda: publisher.get_subscription_count() > 0,
               f"recorder matched on {publisher.topic_name}")
    publisher.publish(msg)
    assert publisher.wait_for_all_acked(Duration(seconds=READY_TIMEOUT)), recorder.output()[-400:]


def _offered_qos(bag: Path) -> dict[str, list[tuple[str, int, str]]]:
    """Return each topic's ``offered_qos_profiles`` (history, depth, reliability) in ``bag``."""
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    out = {}
    for entry in meta["topics_with_message_count"]:
        topic = entry["topic_metadata"]
        profiles = topic["offered_qos_profiles"]
        if isinstance(profiles, str):  # older metadata versions embed a YAML string
            profiles = yaml.safe_load(profiles)
        out[topic["name"]] = [(q["history"], q["depth"], q["reliability"]) for q in profiles]
    return out


def test_missed_messages_come_from_publication_sequence_numbers() -> None:
    count = TopicCount("std_msgs/msg/Float64MultiArray")
    assert count.missed_text() == "unknown"  # nothing received: not a silent 0
    for sequence in (5, 6, 7, 9, 10):  # joined after 4, lost 8
        count.note_sequence(sequence)
    assert count.missed == 5
    assert count.missed_text() == "5"
    unsupported = TopicCount("std_msgs/msg/Float64MultiArray")
    unsupported.note_sequence(0)  # a middleware without sequence numbers
    assert unsupported.missed_text() == "unknown"
    on_time = TopicCount("std_msgs/msg/Float64MultiArray")
    for sequence in (1, 2, 3):
        on_time.note_sequence(sequence)
    assert on_time.missed_text() == "0"


def test_not_received_counts_announced_messages_beyond_the_newest_sequence() -> None:
    # a hole at the end shows in no sequence number: only the publisher's announced count
    tail = TopicCount("std_msgs/msg/Float64MultiArray")
    for sequence in range(1, 221):
        tail.note_sequence(sequence)
    tail.announced = 401
    assert tail.missed == 0 and tail.not_received() == 181
    gap_and_tail = TopicCount("std_msgs/msg/Float64MultiArray")
    for sequence in (3, 4, 7):
        gap_and_tail.note_sequence(sequence)
    gap_and_tail.announced = 9
    assert gap_and_tail.not_received() == 2 + 2 + 2  # before joining, the gap, the tail
    nothing = TopicCount("std_msgs/msg/Float64MultiArray", announced=5)
    assert nothing.not_received() == 5
    assert TopicCount("std_msgs/msg/Float64MultiArray").not_received_text() == "unknown"


def test_bring_up_reads_holes_from_the_recorders_closing_log() -> None:
    from es_bringup.invariants import InvariantReport, check_recorder, recorder_counts_from_log

    lines = [
        "[INFO] [1.0] [record.summary]: /dm/displacement: received 220, written 220, lost "
        "before reception 0, missed 0, not received 181",
        "[INFO] [1.0] [record.summary]: /dm/command: received 400, written 400, lost before "
        "reception 0, missed 0, not received 0",
        "[INFO] [1.0] [record.summary]: /diagnostics: received 9, written 9, lost before "
        "reception 0, missed unknown, not received unknown",
    ]
    counts = recorder_counts_from_log(lines)
    assert counts["/dm/displacement"].not_received == 181
    assert counts["/dm/command"].not_received == 0 and counts["/diagnostics"].received == 9
    report = InvariantReport()
    check_recorder(counts, report)
    assert report.failures == [
        "/dm/displacement: 181 published messages not received by the recorder"]


def test_recorder_reports_what_it_missed_by_joining_late(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    with ros_node("es_record_late") as node:
        command = node.create_publisher(Float64MultiArray, COMMAND, PUBLISHER_QOS)
        for k in range(7):  # nobody records these
            command.publish(grid_to_msg(np.full((2, 2), float(k))))
        recorder = NodeProcess("es_recordings", "record", ["-o", str(bag), COMMAND])
        latest: dict[str, int] = {}
        reports = node.create_subscription(
            DiagnosticArray,
            DIAGNOSTICS,
            lambda msg: latest.update(_written_counts(msg)),
            qos_for(DIAGNOSTICS),
        )
        try:
            wait_matched(node, [command, reports], processes=[recorder])
            for k in range(3):
                command.publish(grid_to_msg(np.full((2, 2), float(k))))
            _wait_written(node, recorder, latest, {COMMAND: 3})
        finally:
            assert recorder.stop(signal.SIGINT) == 0, recorder.output()
    assert "/dm/command: received 3, written 3, lost before reception 0, missed 7" in (
        recorder.output()
    )


def test_recorder_stamps_with_sim_time(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    args = ["-o", str(bag), COMMAND, "--ros-args", "-p", "use_sim_time:=true"]
    recorder = NodeProcess("es_recordings", "record", args)
    try:
        with ros_node("es_record_clock") as node:
            clock = node.create_publisher(Clock, CLOCK, qos_for(CLOCK))
            command = node.create_publisher(Float64MultiArray, COMMAND, PUBLISHER_QOS)
            latest: dict[str, int] = {}
            stamps: list[float] = []

            def on_report(msg: DiagnosticArray) -> None:
                stamps.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
                latest.update(_written_counts(msg))

            reports = node.create_subscription(
                DiagnosticArray, DIAGNOSTICS, on_report, qos_for(DIAGNOSTICS)
            )

            def tick() -> None:
                clock.publish(Clock(clock=Time(sec=100, nanosec=250_000_000)))

            node.create_timer(0.02, tick)
            wait_matched(node, [clock, command, reports], processes=[recorder])
            # its reports carry its clock: once one says 100.25 s, so does every stamp after
            wait_until(
                node,
                lambda: bool(stamps) and stamps[-1] == 100.25,
                f"recorder report stamped 100.25 s (last {stamps[-1:]})",
                processes=[recorder],
            )
            for k in range(20):
                command.publish(grid_to_msg(np.full((2, 2), float(k))))
            _wait_written(node, recorder, latest, {COMMAND: 20})
    finally:
        assert recorder.stop(signal.SIGINT) == 0, recorder.output()
    series = read_bag(bag)[COMMAND]
    assert len(series) == 20
    np.testing.assert_array_equal(series.times, np.full(20, 100.25))


def test_recorder_throughput_loses_nothing(tmp_path: Path) -> None:
    """1000 grids of 64 x 64 doubles at about 1 kHz (a test of loss, not of speed)."""
    grid = np.zeros((64, 64))
    msgs = []
    for i in range(1000):
        grid[0, 0] = i
        msgs.append(grid_to_msg(grid))
    bag = tmp_path / "bag"
    recorder = NodeProcess(
        "es_recordings", "record", ["-o", str(bag), "--storage", "sqlite3", COMMAND]
    )
    try:
        with ros_node("es_record_rate") as node:
            _record_and_publish(node, recorder, {COMMAND: msgs})
    finally:
        code = recorder.stop(signal.SIGTERM)
    assert code == 0, recorder.output()
    values = read_bag(bag)[COMMAND].values
    assert values is not None
    np.testing.assert_array_equal(values[:, 0, 0], np.arange(1000.0))


def _bag_count(bag: Path, topic: str) -> int:
    """Messages of ``topic`` readable from a bag that may still be being written (0: none)."""
    try:
        return len(read_bag(bag, [topic])[topic])
    except (BagError, KeyError):
        return 0


def test_sigkilled_recorder_bag_is_readable_up_to_last_flush(tmp_path: Path) -> None:
    grids = np.random.default_rng(3).normal(size=(200, 3, 3))
    bag = tmp_path / "bag"
    recorder = NodeProcess(
        "es_recordings", "record", ["-o", str(bag), "--flush-interval", "0.1", COMMAND]
    )
    try:
        with ros_node("es_record_kill") as node:
            _record_and_publish(node, recorder, {COMMAND: [grid_to_msg(g) for g in grids]})
        poll_until(lambda: _bag_count(bag, COMMAND) == len(grids), "every message flushed")
    finally:
        code = recorder.stop(signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert not (bag / "metadata.yaml").exists()
    got = read_bag(bag)[COMMAND].values
    assert got is not None
    np.testing.assert_array_equal(got, grids)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "the following arguments are required: -o/--output"),
        (["-o", "{tmp}/bag"], "give at least one TOPIC or --all-dm"),
        (["-o", "{tmp}/bag", "--storage", "rosbag1", "/x"], "invalid choice: 'rosbag1'"),
        (["-o", "{tmp}/bag", "/bad topic"], "invalid topic name '/bad topic'"),
        (["-o", "{tmp}", "/dm/command"], "exists already"),
        (["-o", "{tmp}/bag", "--report-period", "0", "/x"], "--report-period must be in"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    command = [str(executable("es_recordings", "record")), *(a.format(tmp=tmp_path) for a in args)]
    proc = subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert message in lines[0]
