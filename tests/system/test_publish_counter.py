"""Nodes count what they publish (the 'published == recorded' invariant's left side)."""

from __future__ import annotations

from std_msgs.msg import Float64MultiArray
from support import ros

from es_msgs_py.topics import COMMAND, DM_QOS
from es_node_runtime.node_main import PublishCounter


def test_counter_counts_every_publish_per_topic_and_logs_them() -> None:
    with ros.test_node("counter_test") as node:
        pub = node.create_publisher(Float64MultiArray, COMMAND, DM_QOS)
        counter = PublishCounter(node)
        for _ in range(3):
            pub.publish(Float64MultiArray())
        assert counter.counts[COMMAND] == 3
        assert f"published {COMMAND}: 3" in counter.log_lines()
