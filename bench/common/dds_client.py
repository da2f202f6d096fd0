"""The benchmarks' DDS client: an in-process rclpy node that times set point -> command.

Used by the feedforward, feedforward_load, scale and multihost sections.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from std_msgs.msg import Float64MultiArray

#: Set points in flight during the rate measurement (far below the /dm QoS depth).
RATE_WINDOW = 4


#: Set-point rate [Hz] of the paced latency run (the issue's 1 kHz).
PACED_RATE = 1000.0


class DdsClient:
    """In-process rclpy node that feeds set points and times the commands coming back."""

    def __init__(self, shape: tuple[int, int]) -> None:
        import rclpy
        from rclpy.experimental import EventsExecutor
        from rclpy.serialization import serialize_message
        from std_msgs.msg import Float64MultiArray

        from es_msgs_py.arrays import grid_to_msg
        from es_msgs_py.topics import COMMAND, SETPOINT, TEMPERATURE, qos_for
        from es_node_runtime.middleware import configure_middleware
        from es_physics.laws import z_sat
        from es_physics.params import ActuatorParams

        self.shape = shape
        configure_middleware()  # the nodes' profile (takes effect before the first context)
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("bench_client", context=self.context)
        # the nodes' executor: rclpy's SingleThreadedExecutor rebuilt its wait set in Python
        # on every wake-up and cost the client 0.50 ms of CPU per 66 x 66 set point at 2 kHz
        # (0.26 ms on this one), a core of the machine the nodes under test share
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.setpoint_pub = self.node.create_publisher(Float64MultiArray, SETPOINT,
                                                       qos_for(SETPOINT))
        self.temperature_pub = self.node.create_publisher(Float64MultiArray, TEMPERATURE,
                                                          qos_for(TEMPERATURE))
        self.sent = 0
        self.received = 0
        self.received_at: list[float] = []
        self._last_command_cdr: bytes | None = None
        #: publish times [s, perf_counter] of the last paced run's set points, and the
        #: reception times of their commands (empty when some were lost)
        self.paced_sent_at = np.empty(0)
        self.paced_received_at = np.empty(0)
        # Commands and set points cross as CDR bytes: the client only times the commands, so
        # building rclpy message objects per message (as a node must) would be the
        # instrument's own load on the cores the nodes under test share (0.04 ms per
        # 66 x 66 message each way, measured on the relay)
        self.command_sub = self.node.create_subscription(
            Float64MultiArray, COMMAND, self._on_command, qos_for(COMMAND), raw=True)
        # Set points from 10 % to 60 % of z_sat at 46 degC, changing from message to message.
        reach = float(z_sat(46.0, ActuatorParams()))
        phases = np.random.default_rng(0).uniform(0, 2 * np.pi, shape)
        self.messages = [
            serialize_message(grid_to_msg(reach * (0.35 + 0.25 * np.sin(phases + k * 0.4))))
            for k in range(16)
        ]
        self.temperature = grid_to_msg(np.full(shape, 46.0))

    def _on_command(self, msg: Any) -> None:
        self.received += 1
        self.received_at.append(time.perf_counter())
        self._last_command_cdr = msg

    @property
    def last_command(self) -> Float64MultiArray | None:
        """The last command received, or ``None`` before the first."""
        from rclpy.serialization import deserialize_message
        from std_msgs.msg import Float64MultiArray

        cdr = self._last_command_cdr
        return None if cdr is None else deserialize_message(cdr, Float64MultiArray)

    def publish(self, msg: Any) -> None:
        """Publish one set point (counted in ``sent``)."""
        self.setpoint_pub.publish(msg)
        self.sent += 1

    def wait_for_peer(self, setpoint_readers: int = 1, estimates: bool = False,
                      timeout: float = 60.0) -> None:
        """Wait until the client's endpoints matched their peers.

        Peers: ``setpoint_readers`` subscriptions of its set points (the node, a recorder),
        the node's estimate subscription when ``estimates``, the node's command publisher.

        Raises:
            RuntimeError: not matched within ``timeout`` (names what is missing).

        """
        wanted = [("set-point subscriptions", self.setpoint_pub.get_subscription_count,
                   setpoint_readers),
                  ("command publishers", self.command_sub.get_publisher_count, 1)]
        if estimates:
            wanted.append(("estimate subscriptions",
                           self.temperature_pub.get_subscription_count, 1))
        deadline = time.monotonic() + timeout
        while (missing := [f"{what} {count()} of {n}" for what, count, n in wanted
                           if count() < n]):
            if time.monotonic() > deadline:
                raise RuntimeError(f"not matched within {timeout:g} s: {', '.join(missing)}")
            self.executor.spin_once(timeout_sec=0.05)

    def use_temperature(self, timeout: float = 60.0) -> None:
        """Send the estimate, then set points until a command shows it was taken (not 0 V).

        Raises:
            RuntimeError: every command within ``timeout`` was 0 V (the estimate never came).

        """
        from es_msgs_py.arrays import msg_to_grid

        self.temperature_pub.publish(self.temperature)
        deadline = time.monotonic() + timeout
        while True:
            self.latencies(1)
            assert self.last_command is not None
            if np.any(msg_to_grid(self.last_command) > 0.0):
                return
            if time.monotonic() > deadline:
                raise RuntimeError("feedforward holds (all 0 V): temperature not taken within "
                                   f"{timeout:g} s")

    def _wait_received(self, count: int, timeout: float) -> int:
        """Spin until ``count`` commands arrived or ``timeout`` s; return how many are missing."""
        deadline = time.monotonic() + timeout
        while self.received < count and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)
        return max(count - self.received, 0)

    def latencies(self, samples: int) -> np.ndarray:
        """Ping-pong: send one set point, wait for its command; return latencies [s]."""
        out = np.empty(samples)
        for i in range(samples):
            target = self.received + 1
            start = time.perf_counter()
            self.publish(self.messages[i % len(self.messages)])
            if self._wait_received(target, 10.0):
                raise RuntimeError(f"no command came back within 10 s (set point {self.sent})")
            out[i] = self.received_at[-1] - start
        return out

    def paced(self, rate_hz: float, seconds: float) -> tuple[np.ndarray | None, float, int]:
        """Send set points at ``rate_hz`` for ``seconds``; return (latencies, rate, lost).

        Latencies in s, the rate the client achieved in Hz, lost: commands that did not come
        back within 10 s. Commands come back in order (reliable QoS, one per set point), so
        the k-th command answers the k-th set point; when some are lost that pairing is gone
        and the latencies are ``None``.
        """
        period = 1.0 / rate_hz
        count = round(seconds * rate_hz)
        sent_at = np.empty(count)
        first = self.received
        first_index = len(self.received_at)
        start = time.perf_counter()
        for k in range(count):
            due = start + k * period
            while (left := due - time.perf_counter()) > 0.0:
                self.executor.spin_once(timeout_sec=left)
            sent_at[k] = time.perf_counter()
            self.publish(self.messages[k % len(self.messages)])
        self.paced_sent_at = sent_at
        sent_rate = (count - 1) / (sent_at[-1] - sent_at[0])
        lost = self._wait_received(first + count, 10.0)
        if lost:
            self.paced_received_at = np.empty(0)
            return None, sent_rate, lost
        received_at = np.asarray(self.received_at[first_index:first_index + count])
        self.paced_received_at = received_at
        return received_at - sent_at, sent_rate, 0

    def rate(self, seconds: float) -> tuple[float, int]:
        """Keep RATE_WINDOW set points in flight for ``seconds``; return (rate, lost).

        Rate: commands per second; lost: commands that did not come back within 10 s.
        """
        sent = 0
        first = self.received
        start = time.perf_counter()
        last_progress = time.monotonic()
        seen = self.received
        while time.perf_counter() - start < seconds:
            while sent - (self.received - first) < RATE_WINDOW:
                self.publish(self.messages[sent % len(self.messages)])
                sent += 1
            self.executor.spin_once(timeout_sec=0.05)
            if self.received != seen:
                seen, last_progress = self.received, time.monotonic()
            elif time.monotonic() - last_progress > 5.0:
                break  # commands stopped coming back: the drain below counts the lost ones
        elapsed = time.perf_counter() - start
        done = self.received - first
        return done / elapsed, self._wait_received(first + sent, 10.0)

    def close(self) -> None:
        """Shut the executor down, destroy the node and shut its context down.

        The EventsExecutor must be shut down first: otherwise it keeps the node's DDS entities
        alive after ``destroy_node`` (8 threads per closed client), and every later run of a
        benchmark process pays for the earlier clients still receiving its messages.
        """
        self.executor.shutdown()
        self.node.destroy_node()
        import rclpy

        rclpy.shutdown(context=self.context)
