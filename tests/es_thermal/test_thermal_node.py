"""The thermal node as a process over DDS: estimates, faults, recovery, diagnostics."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray
from support.ros import READY_TIMEOUT, NodeProcess, node_process, spin_until, wait_matched
from support.ros import test_node as ros_node

from es_msgs_py import topics
from es_msgs_py.arrays import grid_to_msg, msg_to_grid, sensors_to_msg
from es_msgs_py.diagnostics import Level, level_of
from es_thermal.thermal_node import ThermalNode

pytestmark = pytest.mark.dds

SHAPE = (4, 4)
SENSORS = 4  # one per 2 x 2 block
RNG = np.random.default_rng(5)


@dataclass
class Harness:
    """A test node wired to the thermal node's topics."""

    node: Node
    estimates: list[np.ndarray] = field(default_factory=list)
    diagnostics: dict[str, DiagnosticStatus] = field(default_factory=dict)

    def __post_init__(self) -> None:
        node = self.node
        self.estimate_sub = node.create_subscription(
            Float64MultiArray,
            topics.TEMPERATURE,
            lambda msg: self.estimates.append(msg_to_grid(msg, SHAPE)),
            topics.qos_for(topics.TEMPERATURE),
        )
        self.diag_sub = node.create_subscription(
            DiagnosticArray, topics.DIAGNOSTICS, self._on_diag, topics.qos_for(topics.DIAGNOSTICS)
        )
        self.raw = node.create_publisher(
            Float64MultiArray, topics.TEMPERATURE_RAW, topics.qos_for(topics.TEMPERATURE_RAW)
        )
        self.heat = node.create_publisher(
            Float64MultiArray, topics.HEAT_LOAD, topics.qos_for(topics.HEAT_LOAD)
        )

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith("thermal: "):
                self.diagnostics[status.name.removeprefix("thermal: ")] = status

    def wait_connected(self, proc: NodeProcess) -> None:
        """Wait until every endpoint matched the node's (matched, not merely on the graph:
        a message sent before is lost)."""
        endpoints = [self.raw, self.heat, self.estimate_sub, self.diag_sub]
        wait_matched(self.node, endpoints, processes=[proc])

    def exchange(self, msg: Float64MultiArray, expect: bool = True) -> np.ndarray | None:
        """Publish one raw message; return the estimate it produced (None if none came)."""
        before = len(self.estimates)
        self.raw.publish(msg)
        # an estimate comes within the bounded wait; a rejected message gets none (checked
        # for 0.5 s: absence cannot be waited for)
        timeout = READY_TIMEOUT if expect else 0.5
        got = spin_until(self.node, lambda: len(self.estimates) > before, timeout)
        assert got == expect, f"estimate {'missing' if expect else 'published'}"
        return self.estimates[-1] if got else None

    def diagnostic(
        self,
        aspect: str,
        check: Callable[[DiagnosticStatus], bool],
        timeout: float = READY_TIMEOUT,
    ) -> DiagnosticStatus:
        self.diagnostics.pop(aspect, None)
        assert spin_until(
            self.node,
            lambda: aspect in self.diagnostics and check(self.diagnostics[aspect]),
            timeout,
        ), f"no matching diagnostic {aspect}: {self.diagnostics.get(aspect)}"
        return self.diagnostics[aspect]


def readings(value: float = 40.0) -> np.ndarray:
    return value + 0.01 * RNG.standard_normal(SENSORS)


def is_level(level: Level) -> Callable[[DiagnosticStatus], bool]:
    return lambda s: level_of(s) == level


@contextmanager
def started(stale_timeout: float) -> Iterator[tuple[Harness, NodeProcess]]:
    """The node at 4 x 4 with ``fault.stale_timeout`` [s], and a harness matched to it."""
    args = [
        "--ros-args",
        "-p", "rows:=4", "-p", "cols:=4", "-p", "sensor_pitch:=2",
        "-p", "time_scale:=0.05", "-p", "diagnostics_period:=0.2",
        "-p", f"fault.stale_timeout:={stale_timeout}", "-p", "model.sensor_noise:=0.01",
        "-p", "ready_subscribers:=1",
    ]  # fmt: skip
    with node_process("es_thermal", "thermal_node", args) as proc, ros_node("thermal_test") as node:
        h = Harness(node)
        h.wait_connected(proc)
        # matched on the node's side too: our estimate subscription matched the node's
        # publisher before the node's publisher matched it, and the first estimate, sent to
        # no reader yet, was lost (seen at load 4-8: "estimate missing" on the first exchange)
        h.diagnostic("ready", is_level(Level.OK))
        yield h, proc


@pytest.fixture
def harness() -> Iterator[tuple[Harness, NodeProcess]]:
    # the raw input never goes stale between two steps, however slow a loaded machine makes
    # them (a diagnostic awaited as OK would say ERROR): staleness has its own test
    with started(stale_timeout=600.0) as h_proc:
        yield h_proc


def test_node_estimates_faults_and_recovery(harness: tuple[Harness, NodeProcess]) -> None:
    h, proc = harness
    # One estimate per raw message, per actuator, near the readings.
    h.heat.publish(grid_to_msg(np.zeros(SHAPE)))
    for _ in range(5):
        estimate = h.exchange(sensors_to_msg(readings()))
    assert estimate is not None and estimate.shape == SHAPE
    np.testing.assert_allclose(estimate, 40.0, atol=0.05)
    assert h.diagnostic("sensors", is_level(Level.OK)).message == "all sensors valid"
    # its raw input is matched (this harness publishes it): it says it is ready
    assert h.diagnostic("ready", is_level(Level.OK)).message == "ready"

    # A NaN and an out-of-range sensor: excluded, the estimate continues from the others.
    bad = readings()
    bad[1], bad[2] = np.nan, 900.0
    estimate = h.exchange(sensors_to_msg(bad))
    assert estimate is not None and np.all(np.isfinite(estimate))
    np.testing.assert_allclose(estimate, 40.0, atol=0.05)
    status = h.diagnostic("sensors", is_level(Level.WARN))
    values = {kv.key: kv.value for kv in status.values}
    assert (values["non_finite"], values["out_of_range"], values["valid"]) == ("1", "1", "2")
    assert values["first_excluded"] == "1, 2"

    # Wrong size and wrong layout: rejected, nothing published, diagnostic WARN.
    assert h.exchange(sensors_to_msg(readings()[:3]), expect=False) is None
    assert h.exchange(grid_to_msg(np.full((2, 2), 40.0)), expect=False) is None
    h.heat.publish(grid_to_msg(np.full(SHAPE, np.nan)))  # a heat load with NaN
    status = h.diagnostic(
        "input", lambda s: {kv.key: kv.value for kv in s.values}["rejected_heat_load"] == "1"
    )
    assert level_of(status) == Level.WARN and "rejected" in status.message
    assert {kv.key: kv.value for kv in status.values}["rejected_raw"] == "2"

    # Every sensor dead: no estimate (the feedforward holds), diagnostic ERROR ...
    assert h.exchange(sensors_to_msg(np.full(SENSORS, np.nan)), expect=False) is None
    assert "no valid sensor" in h.diagnostic("sensors", is_level(Level.ERROR)).message
    # ... and recovery by itself when valid readings return.
    estimate = h.exchange(sensors_to_msg(readings(40.1)))
    assert estimate is not None and np.all(np.isfinite(estimate))
    h.diagnostic("sensors", is_level(Level.OK))

    estimate_status = h.diagnostic("estimate", lambda s: True)
    assert {kv.key for kv in estimate_status.values} >= {"estimator", "update_ms_mean"}

    # An absurd heat load: rejected (WARN, reason given), the last heat load held.
    h.heat.publish(grid_to_msg(np.full(SHAPE, 1e12)))
    status = h.diagnostic(
        "input", lambda s: {kv.key: kv.value for kv in s.values}["rejected_heat_load"] == "2"
    )
    assert "max_heat_load" in {kv.key: kv.value for kv in status.values}["last_rejection"]
    estimate = h.exchange(sensors_to_msg(readings()))
    assert estimate is not None
    np.testing.assert_allclose(estimate, 40.0, atol=0.05)
    assert proc.process.poll() is None  # nothing crashed the node


def test_stale_input_is_an_error_until_readings_return() -> None:
    with started(stale_timeout=1.0) as (h, proc):
        assert h.exchange(sensors_to_msg(readings())) is not None
        # No raw message for longer than the stale timeout: ERROR ...
        time.sleep(1.3)  # the scenario, not a wait for readiness: the input ages past 1 s
        assert "no /dm/temperature/raw" in h.diagnostic("sensors", is_level(Level.ERROR)).message
        # ... and recovery once readings stream again (a stream at 10 Hz: one reading would
        # age past 1 s again before a diagnostic if the machine stalls the node that long)
        before = len(h.estimates)
        h.diagnostics.pop("sensors", None)
        deadline = time.monotonic() + READY_TIMEOUT
        while not (h.diagnostics.get("sensors") and level_of(h.diagnostics["sensors"]) == Level.OK):
            assert time.monotonic() < deadline, f"sensors never OK: {h.diagnostics.get('sensors')}"
            h.raw.publish(sensors_to_msg(readings()))
            spin_until(h.node, lambda: False, 0.1)
        assert len(h.estimates) > before
        assert proc.process.poll() is None


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["-p", "sensor_positions:=[0.5, 0.5, 9.0]"], "even count"),
        (["-p", "sensor_positions:=[0.5, 99.0]"], "outside"),
    ],
)
def test_invalid_configuration_exits_with_one_line(args: list[str], reason: str) -> None:
    proc = NodeProcess("es_thermal", "thermal_node", ["--ros-args", *args])
    try:
        proc.process.wait(READY_TIMEOUT)
    finally:
        code = proc.stop()
    lines = [line for line in proc.output().splitlines() if line.strip()]
    assert code == 2, proc.output()
    assert reason in lines[-1] and "Traceback" not in proc.output()


def test_timer_mode_publishes_at_its_rate_until_the_input_goes_stale() -> None:
    args = [
        "--ros-args",
        "-p", "rows:=4", "-p", "cols:=4", "-p", "sensor_pitch:=2", "-p", "estimator:=lowpass",
        "-p", "publish_rate:=20.0", "-p", "fault.stale_timeout:=2.0",
    ]  # fmt: skip
    with (
        node_process("es_thermal", "thermal_node", args) as proc,
        ros_node("thermal_timer_test") as node,
    ):
        h = Harness(node)
        h.wait_connected(proc)
        h.raw.publish(sensors_to_msg(readings()))
        # One raw message, several estimates at 20 Hz (40 within the 2 s: 3 even when the
        # machine is busy) ...
        assert spin_until(node, lambda: len(h.estimates) >= 3, READY_TIMEOUT)
        # ... until the raw stream is stale (2 s): then the estimates stop.
        deadline = time.monotonic() + READY_TIMEOUT
        stopped = False
        while not stopped and time.monotonic() < deadline:
            before = len(h.estimates)
            spin_until(node, lambda: False, 0.6)
            stopped = len(h.estimates) == before
        assert stopped


def test_a_failing_update_is_reported_and_the_node_keeps_running(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Whatever the core raises stays inside the callback: ERROR, then a fresh estimate."""
    context = rclpy.Context()
    rclpy.init(args=["--ros-args", "-p", "rows:=2", "-p", "cols:=2"], context=context)
    monkeypatch.setattr(rclpy.node, "get_default_context", lambda: context)
    node = ThermalNode()
    try:
        node._on_heat_load(grid_to_msg(np.zeros((2, 2))))
        node._on_raw(sensors_to_msg(np.full(4, 40.0)))
        assert node.health.published == 1

        def fail_update(*_: object) -> None:
            raise np.linalg.LinAlgError("Singular matrix")

        def fail_heat_load(*_: object) -> None:
            raise RuntimeError("unexpected")

        with monkeypatch.context() as patch:
            patch.setattr(node.core, "update", fail_update)
            patch.setattr(node.core, "set_heat_load", fail_heat_load)
            node._on_heat_load(grid_to_msg(np.zeros((2, 2))))
            node._on_raw(sensors_to_msg(np.full(4, 40.0)))
        assert node.health.published == 1  # nothing published for the failed update
        level, message, values = node.health.estimate_status(
            node.core.model, None, node._wall_now()
        )
        assert level == Level.ERROR and "failed" in message
        assert values["failed_updates"] == 2
        assert "LinAlgError: Singular matrix" in str(values["last_failure"])
        # The estimate restarts from the next readings (a filter would still be near 40).
        node._on_raw(sensors_to_msg(np.full(4, 45.0)))
        assert node.health.published == 2
        latest = node.core.latest
        assert latest is not None and latest.temperatures is not None
        np.testing.assert_allclose(latest.temperatures, 45.0)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
