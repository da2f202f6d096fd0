"""es_node_runtime.node_main.deliver_pending: a stopping node waits, bounded, until its readers
have acknowledged what it published, and names the topics they have not."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.duration import Duration
from std_msgs.msg import Float64MultiArray
from support.ros import READY_TIMEOUT, NodeProcess
from support.ros import test_node as ros_node

from es_msgs_py.arrays import grid_to_msg
from es_msgs_py.topics import COMMAND, qos_for
from es_node_runtime.node_main import deliver_pending

pytestmark = pytest.mark.dds


def test_unacknowledged_messages_are_waited_for_then_named(tmp_path: Path) -> None:
    recorder = NodeProcess("es_recordings", "record", ["-o", str(tmp_path / "bag"), COMMAND])
    stopped = False
    try:
        with ros_node("delivery_test") as node:
            publisher = node.create_publisher(Float64MultiArray, COMMAND, qos_for(COMMAND))
            message = grid_to_msg(np.zeros((2, 3)))
            # the reader has matched us once a message of ours is acknowledged (one-sided
            # matching: its subscription count alone would not say so)
            deadline = time.monotonic() + READY_TIMEOUT
            acknowledged = False
            while not acknowledged and time.monotonic() < deadline:
                publisher.publish(message)
                acknowledged = publisher.get_subscription_count() > 0 and (
                    publisher.wait_for_all_acked(Duration(seconds=1.0))
                )
            assert acknowledged, recorder.output()[-400:]
            assert deliver_pending(node, limit=5.0) == []  # nothing pending: at once

            os.kill(recorder.pid, signal.SIGSTOP)  # a reader that cannot acknowledge
            stopped = True
            for _ in range(20):
                publisher.publish(message)
            started = time.monotonic()
            assert deliver_pending(node, limit=0.5) == [COMMAND]
            assert time.monotonic() - started < 5.0  # bounded

            os.kill(recorder.pid, signal.SIGCONT)  # it wakes up: the messages get through
            stopped = False
            assert deliver_pending(node, limit=READY_TIMEOUT) == []
    finally:
        if stopped:
            os.kill(recorder.pid, signal.SIGCONT)
        assert recorder.stop() == 0, recorder.output()[-400:]

