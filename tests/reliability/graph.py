"""Helpers of the fault-injection tests over DDS: node processes and a watching test node.

:class:`Watcher` is an rclpy node spinning in a background thread. It checks every
``/dm/command`` it receives (contract layout, finite, within [0, v_limit]) and every
``/dm/temperature`` (finite), keeps the newest /clock and diagnostics, and lets the test
publish set points, temperatures, raw sensor readings and heat loads and set parameters of
the nodes under test while it keeps watching.
"""

from __future__ import annotations

import os
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.srv import SetParameters
from rclpy.client import Client
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import Float64MultiArray
from support.ros import READY_TIMEOUT, STOP_TIMEOUT, NotReadyError, poll_until, unmatched

from es_bringup.invariants import recorder_counts_from_log
from es_msgs_py import topics
from es_msgs_py.arrays import LayoutError, msg_to_grid
from es_msgs_py.bag import read_bag
from es_physics.laws import DEFAULT_V_LIMIT

#: Estimates outside this range [degC] are nonsense for a mirror (the thermal node's sensor
#: range is -20..120 degC by default).
PLAUSIBLE_DEGC = (-50.0, 200.0)


def _plausible(values: np.ndarray) -> bool:
    return bool(np.all((values >= PLAUSIBLE_DEGC[0]) & (values <= PLAUSIBLE_DEGC[1])))


class Proc:
    """A process started by a test (output to a temporary file), signalled by its PID only."""

    def __init__(self, name: str, command: Sequence[str]) -> None:
        self.name = name
        self.command = list(command)
        self._log: IO[bytes] = tempfile.TemporaryFile()  # noqa: SIM115 - lives with the process
        self.popen = subprocess.Popen(self.command, stdout=self._log, stderr=subprocess.STDOUT,
                                      start_new_session=True)

    def alive(self) -> bool:
        """Whether the process is still running."""
        return self.popen.poll() is None

    def output(self) -> str:
        """Everything it printed so far."""
        self._log.seek(0)
        return self._log.read().decode(errors="replace")

    def kill(self) -> None:
        """SIGKILL: the process gets no chance to clean up."""
        if self.alive():
            os.kill(self.popen.pid, signal.SIGKILL)
            self.popen.wait(10)

    def stop(self, timeout: float = STOP_TIMEOUT) -> int:
        """SIGINT, then SIGKILL after ``timeout``; return the exit code."""
        if self.alive():
            os.kill(self.popen.pid, signal.SIGINT)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()
        return self.popen.returncode

    def published(self, topic: str) -> int | None:
        """The count a node logged at its clean exit (``published <topic>: <n>``)."""
        for line in self.output().splitlines():
            if f"published {topic}: " in line:
                return int(line.rsplit(":", 1)[1])
        return None


def assert_recorded_everything(
    bag: Path, plant: Proc, recorder: Proc, recorded: Sequence[str], context: str = ""
) -> None:
    """Assert that the bag holds every message of ``recorded`` the plant logged it published.

    The recorder's closing lines must name no hole either: it knows of one from the counts
    the plant announced on /diagnostics, which sequence numbers cannot show at a run's end.
    """
    closing = recorder_counts_from_log(recorder.output().splitlines())
    assert all(t in closing and not closing[t].not_received for t in recorded), (
        f"{context}\n{recorder.output()[-1200:]}")
    counts = read_bag(bag, recorded)
    held = {t: (plant.published(t), len(counts[t])) for t in recorded}
    assert all(sent == got for sent, got in held.values()), (
        f"{context}\n(published, recorded): {held}\nplant: {plant.output()[-800:]}\n"
        f"recorder: {recorder.output()[-1200:]}")


@dataclass
class CommandCheck:
    """What the watcher saw on /dm/command."""

    shape: tuple[int, int]
    v_limit: float = DEFAULT_V_LIMIT
    received: int = 0
    non_finite: int = 0
    out_of_limit: int = 0
    bad_layout: int = 0
    last: np.ndarray | None = None
    problems: list[str] = field(default_factory=list)

    def check(self, msg: Float64MultiArray) -> None:
        """Count one command and every way it may be unfit for an actuator."""
        self.received += 1
        try:
            grid = msg_to_grid(msg, self.shape)
        except LayoutError as err:
            self.bad_layout += 1
            self.problems.append(f"layout: {err}")
            return
        if not np.all(np.isfinite(grid)):
            self.non_finite += 1
            self.problems.append(f"non-finite command #{self.received}")
        elif np.any(grid < 0.0) or np.any(grid > self.v_limit):
            self.out_of_limit += 1
            self.problems.append(f"command #{self.received} spans {grid.min()}..{grid.max()} V")
        self.last = grid


#: The /dm topics a controlled lockstep plant publishes (what ``start_subscribers`` counts).
PLANT_OUTPUTS = (topics.DISPLACEMENT, topics.SETPOINT, topics.TEMPERATURE_RAW, topics.HEAT_LOAD)


class Watcher:
    """Test node in a background thread: watches the graph and injects messages."""

    def __init__(self, shape: tuple[int, int], plant_peer: bool = False) -> None:
        """Start the watcher; ``plant_peer`` also subscribes to the plant's /dm outputs.

        With ``plant_peer`` a plant started with ``start_subscribers`` counting the watcher
        steps only once the watcher has matched it (those messages are ignored): otherwise a
        short lockstep run can end before discovery between the two completes.
        """
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("reliability_watcher", context=self.context)
        self.lock = threading.Lock()
        self.commands = CommandCheck(shape)
        self.temperatures = 0
        self.non_finite_temperatures = 0
        self.injected_non_finite_temperatures = 0  # the watcher hears its own messages too
        self.injected: dict[str, int] = {}  # messages the watcher published, per topic
        self.implausible_temperatures = 0
        self.injected_implausible_temperatures = 0
        self.clock = -1.0
        self.diagnostics: dict[str, DiagnosticStatus] = {}
        self._parameter_clients: dict[str, Client] = {}
        node = self.node
        self.subscriptions: dict[str, Subscription] = {
            topics.COMMAND: node.create_subscription(
                Float64MultiArray, topics.COMMAND, self._on_command,
                topics.qos_for(topics.COMMAND)),
            topics.TEMPERATURE: node.create_subscription(
                Float64MultiArray, topics.TEMPERATURE, self._on_temperature,
                topics.qos_for(topics.TEMPERATURE)),
            topics.CLOCK: node.create_subscription(
                ClockMsg, topics.CLOCK, self._on_clock, topics.qos_for(topics.CLOCK)),
            topics.DIAGNOSTICS: node.create_subscription(
                DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics,
                topics.qos_for(topics.DIAGNOSTICS)),
        }
        if plant_peer:
            for topic in PLANT_OUTPUTS:
                self.subscriptions[topic] = node.create_subscription(
                    Float64MultiArray, topic, lambda _msg: None, topics.qos_for(topic))
        self.publishers = {
            topic: node.create_publisher(Float64MultiArray, topic, topics.qos_for(topic))
            for topic in (topics.SETPOINT, topics.TEMPERATURE, topics.TEMPERATURE_RAW,
                          topics.HEAT_LOAD)
        }
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # the context shut down under the executor: end the thread
                return

    def _on_command(self, msg: Float64MultiArray) -> None:
        with self.lock:
            self.commands.check(msg)

    def _on_temperature(self, msg: Float64MultiArray) -> None:
        with self.lock:
            self.temperatures += 1
            values = np.frombuffer(msg.data, np.float64)
            if not np.all(np.isfinite(values)):
                self.non_finite_temperatures += 1
            elif not _plausible(values):
                self.implausible_temperatures += 1

    def estimator_non_finite_temperatures(self) -> int:
        """Non-finite /dm/temperature messages that the watcher did not inject itself."""
        with self.lock:
            return self.non_finite_temperatures - self.injected_non_finite_temperatures

    def _on_clock(self, msg: ClockMsg) -> None:
        self.clock = msg.clock.sec + msg.clock.nanosec * 1e-9

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        with self.lock:
            for status in msg.status:
                self.diagnostics[status.name] = status

    def publish(self, topic: str, msg: Float64MultiArray) -> None:
        """Publish ``msg`` on one of the injected topics."""
        if topic == topics.TEMPERATURE:
            values = np.frombuffer(msg.data, np.float64)
            with self.lock:
                if not np.all(np.isfinite(values)):
                    self.injected_non_finite_temperatures += 1
                elif not _plausible(values):
                    self.injected_implausible_temperatures += 1
        self.publishers[topic].publish(msg)
        self.injected[topic] = self.injected.get(topic, 0) + 1

    def estimator_implausible_temperatures(self) -> int:
        """Finite /dm/temperature messages beyond PLAUSIBLE_DEGC not injected by the watcher."""
        with self.lock:
            return self.implausible_temperatures - self.injected_implausible_temperatures

    def wait_matched(self, wanted: Mapping[str, tuple[int, int]], procs: Sequence[Proc],
                     timeout: float = READY_TIMEOUT) -> None:
        """Wait until the watcher's endpoints matched their peers: ``{topic: (publishers its
        subscription needs, subscriptions its publisher needs)}``; the watcher's own
        publisher and subscription of a topic match each other and count.

        Raises:
            NotReadyError: within ``timeout`` some endpoint did not match (each is named), or
                one of ``procs`` died first.

        """
        pairs: list[tuple[Publisher | Subscription, int]] = []
        for topic, (publishers, subscriptions) in wanted.items():
            if publishers:
                pairs.append((self.subscriptions[topic], publishers))
            if subscriptions:
                pairs.append((self.publishers[topic], subscriptions))

        def ready() -> bool:
            dead = [p for p in procs if not p.alive()]
            if dead:
                raise NotReadyError(f"{dead[0].name} exited while the graph started:\n"
                                    f"{dead[0].output()[-1500:]}")
            return not unmatched(pairs)

        try:
            poll_until(ready, "watcher endpoints matched", timeout)
        except NotReadyError as err:
            raise NotReadyError(f"{err} ({'; '.join(unmatched(pairs))})") from None

    def wait_for(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Poll ``condition`` (the watcher keeps spinning) until true or ``timeout`` s pass."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            time.sleep(0.01)
        return condition()

    def command_count(self) -> int:
        """Commands received so far."""
        with self.lock:
            return self.commands.received

    def parameter_client(self, node_name: str, timeout: float = READY_TIMEOUT) -> Client:
        """Return a client of ``/<node_name>/set_parameters`` once the service has matched.

        The client is made once per node and kept: discovery of a service is done while the
        graph is quiet (call this before the part a test measures), not under a fault.

        Raises:
            NotReadyError: the service was not available within ``timeout`` wall seconds.

        """
        client = self._parameter_clients.get(node_name)
        if client is None:
            client = self.node.create_client(SetParameters, f"/{node_name}/set_parameters")
            self._parameter_clients[node_name] = client
        poll_until(client.service_is_ready, f"service /{node_name}/set_parameters", timeout)
        return client

    def set_parameters(self, node_name: str, params: Sequence[Parameter],
                       timeout: float = READY_TIMEOUT) -> list[tuple[bool, str]]:
        """Set parameters of another node one by one; return (successful, reason) of each.

        Raises:
            NotReadyError: the node's parameter service never became available, or did not
                answer a request, within ``timeout`` wall seconds.

        """
        client = self.parameter_client(node_name, timeout)
        outcomes = []
        for param in params:
            request = SetParameters.Request(parameters=[param.to_parameter_msg()])
            future = client.call_async(request)
            if not self.wait_for(future.done, timeout):
                raise NotReadyError(f"no answer from /{node_name}/set_parameters in {timeout:g} s")
            result = future.result().results[0]
            outcomes.append((bool(result.successful), str(result.reason)))
        return outcomes

    def close(self) -> None:
        """Stop spinning, destroy the node, shut the context down."""
        rclpy.try_shutdown(context=self.context)
        self._thread.join(5.0)
        self.node.destroy_node()
