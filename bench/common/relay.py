"""The benchmark's floor for a node over DDS: a plain rclpy relay /dm/setpoint -> /dm/command.

It republishes every received message unchanged (no conversion, no computation), with the
contract QoS and rclpy's default SingleThreadedExecutor, so the feedforward node's rate and
latency can be compared with what plain rclpy costs for the same message size on the same
machine. ``-p executor:=events`` runs it on the EventsExecutor the feedforward node uses (a
second reference). Run as its own process (``bench/run.py`` starts it):

    (cd bench && ../.venv/bin/python -m common.relay [--ros-args -p executor:=events ...])
"""

from __future__ import annotations

import sys

from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from es_msgs_py.topics import COMMAND, SETPOINT, qos_for
from es_node_runtime.node_main import EXECUTOR_PARAMETER, EXECUTORS, run_node
from es_node_runtime.params import ParameterSpec, declare_parameters


class Relay(Node):
    """Subscribe to /dm/setpoint and publish each message as it is on /dm/command."""

    def __init__(self) -> None:
        super().__init__("relay")
        declare_parameters(self, [ParameterSpec(EXECUTOR_PARAMETER, EXECUTORS[0], "Executor.",
                                                choices=EXECUTORS, read_only=True)])
        self._publisher = self.create_publisher(Float64MultiArray, COMMAND, qos_for(COMMAND))
        self.create_subscription(Float64MultiArray, SETPOINT, self._publisher.publish,
                                 qos_for(SETPOINT))


def main() -> int:
    """Run the relay until SIGINT/SIGTERM."""
    return run_node(Relay, sys.argv)


if __name__ == "__main__":
    raise SystemExit(main())
