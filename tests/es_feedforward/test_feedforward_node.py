"""The feedforward node as a process over DDS: commands, safety, diagnostics, reload."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from support.ros import READY_TIMEOUT, NodeProcess, node_process, spin_until, wait_matched
from support.ros import test_node as ros_node

from es_feedforward.feedforward import FeedforwardConfig, Mode
from es_feedforward.param_file import write_params_file
from es_msgs_py import topics
from es_msgs_py.arrays import grid_to_msg, msg_to_grid
from es_msgs_py.diagnostics import Level, level_of
from es_msgs_py.topics import COMMAND, DIAGNOSTICS, SETPOINT, qos_for
from es_physics.laws import hyperbolic_forward, quadratic_forward

from .plantlike import grid_params

pytestmark = pytest.mark.dds

SHAPE = (2, 3)
PARAMS = grid_params(SHAPE, seed=8)
TEMPERATURE = np.array([[41.0, 44.0, 47.0], [49.0, 50.5, 52.0]])
NM = 1e-9
#: Temperature timeout [s] of the node under test outside its stale case (see params_file).
FRESH_S = 600.0


@dataclass
class Harness:
    """A test node wired to the feedforward's topics."""

    node: Node
    commands: list[np.ndarray] = field(default_factory=list)
    diagnostics: dict[str, DiagnosticStatus] = field(default_factory=dict)
    temperatures_sent: int = 0

    def __post_init__(self) -> None:
        node = self.node
        self.command_sub = node.create_subscription(
            Float64MultiArray,
            COMMAND,
            lambda msg: self.commands.append(msg_to_grid(msg, SHAPE)),
            qos_for(COMMAND),
        )
        self.diag_sub = node.create_subscription(
            DiagnosticArray, DIAGNOSTICS, self._on_diag, qos_for(DIAGNOSTICS)
        )
        self.setpoint = node.create_publisher(Float64MultiArray, SETPOINT, qos_for(SETPOINT))
        self.temperature = node.create_publisher(
            Float64MultiArray, topics.TEMPERATURE, qos_for(topics.TEMPERATURE)
        )
        self.set_client = node.create_client(SetParameters, "/feedforward/set_parameters")

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith("feedforward: "):
                self.diagnostics[status.name.removeprefix("feedforward: ")] = status

    def wait_connected(self, proc: NodeProcess) -> None:
        """Wait until every endpoint matched the node's (matched, not merely on the graph:
        a message sent before is lost)."""
        endpoints = [self.setpoint, self.temperature, self.command_sub, self.diag_sub]
        wait_matched(self.node, endpoints, processes=[proc])

    def send_temperature(self, grid: np.ndarray) -> None:
        """Publish an estimate and wait until the node reports it received (its temperature
        diagnostic counts them): a set point sent after it then finds it."""
        self.temperature.publish(grid_to_msg(grid))
        self.temperatures_sent += 1
        sent = self.temperatures_sent
        self.diagnostic(
            "temperature", lambda s: int(values_of(s).get("received", "0")) >= sent, READY_TIMEOUT
        )

    def exchange(self, msg: Float64MultiArray) -> np.ndarray:
        """Publish one set point message and return the command it produced."""
        before = len(self.commands)
        self.setpoint.publish(msg)
        assert spin_until(self.node, lambda: len(self.commands) > before, READY_TIMEOUT), (
            f"no /dm/command answered set point {before + 1} within {READY_TIMEOUT:g} s"
        )
        return self.commands[-1]

    def diagnostic(
        self, aspect: str, predicate: object = None, timeout: float = READY_TIMEOUT
    ) -> DiagnosticStatus:
        """Wait for a diagnostic of ``aspect`` satisfying ``predicate`` (any when None)."""
        self.diagnostics.pop(aspect, None)
        check = predicate if callable(predicate) else (lambda s: True)
        assert spin_until(
            self.node,
            lambda: aspect in self.diagnostics and check(self.diagnostics[aspect]),
            timeout,
        ), f"no matching diagnostic {aspect}: {self.diagnostics.get(aspect)}"
        return self.diagnostics[aspect]

    def set_parameters(self, **values: object) -> SetParameters.Response:
        assert self.set_client.wait_for_service(timeout_sec=READY_TIMEOUT)
        request = SetParameters.Request()
        request.parameters = [
            Parameter(name.replace("__", "."), value=value).to_parameter_msg()
            for name, value in values.items()
        ]
        future = self.set_client.call_async(request)
        assert spin_until(self.node, future.done, READY_TIMEOUT), "no set_parameters response"
        response = future.result()
        assert response is not None
        return response


def values_of(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


@pytest.fixture
def params_file(tmp_path: Path) -> Path:
    path = tmp_path / "feedforward.yaml"
    # an estimate is fresh for the whole test however slow a loaded machine makes its steps;
    # the stale case lowers the timeout at run time
    write_params_file(path, FeedforwardConfig(shape=SHAPE, params=PARAMS,
                                              temperature_timeout=FRESH_S))
    return path


@pytest.fixture
def harness(params_file: Path) -> Iterator[tuple[Harness, NodeProcess]]:
    args = ["--ros-args", "--params-file", str(params_file), "-p", "diagnostics_period:=0.2"]
    with (
        node_process("es_feedforward", "feedforward_node", args) as proc,
        ros_node("ff_test") as node,
    ):
        h = Harness(node)
        h.wait_connected(proc)
        yield h, proc


def test_node_commands_safety_and_reload(harness: tuple[Harness, NodeProcess]) -> None:
    h, proc = harness
    z = np.array([[10.0, 50.0, 90.0], [120.0, 60.0, 5.0]]) * NM

    # its inputs are matched: it says it is ready
    assert h.diagnostic("ready", lambda s: level_of(s) == Level.OK).message == "ready"
    # no temperature yet: the held (zero) command is still published, counted, WARN, logged
    assert np.all(h.exchange(grid_to_msg(z)) == 0.0)
    assert level_of(h.diagnostic("temperature")) == Level.ERROR
    held = h.diagnostic("actuators", lambda s: level_of(s) == Level.WARN)
    assert "holding the last good command" in held.message
    assert "no temperature received yet" in held.message
    assert values_of(held)["held"] == "1"
    assert spin_until(h.node, lambda: "0 V: no good command yet" in proc.output(), READY_TIMEOUT)

    # per-actuator maps from the parameters file: the command reproduces z on the model
    h.send_temperature(TEMPERATURE)
    command = h.exchange(grid_to_msg(z))
    np.testing.assert_allclose(hyperbolic_forward(command, TEMPERATURE, PARAMS), z, atol=1e-5 * NM)
    good = command
    assert level_of(h.diagnostic("temperature", lambda s: level_of(s) == Level.OK)) == Level.OK

    # wrong size: rejected with a diagnostic, the last good command is re-published
    wrong = grid_to_msg(np.zeros((3, 2)))
    np.testing.assert_array_equal(h.exchange(wrong), good)
    status = h.diagnostic("setpoint", lambda s: level_of(s) == Level.ERROR)
    assert "expected 2 x 3" in status.message
    assert values_of(status)["held"] == "2"  # the rejected set point's command was held
    held = h.diagnostic("actuators", lambda s: "set point rejected" in s.message)
    assert level_of(held) == Level.WARN
    # wrong layout (labels) as well
    bad_layout = grid_to_msg(z)
    bad_layout.layout.dim = [MultiArrayDimension(label="sensor", size=6, stride=6)]
    np.testing.assert_array_equal(h.exchange(bad_layout), good)

    # NaN, negative and unreachable set points: clipped/held per actuator, aggregated diagnostic
    odd = z.copy()
    odd[0, 0], odd[0, 1], odd[1, 2] = np.nan, -3 * NM, 1e-6
    command = h.exchange(grid_to_msg(odd))
    assert command[0, 0] == good[0, 0]
    assert command[0, 1] == 0.0
    assert command[1, 2] == 350.0
    status = h.diagnostic("actuators", lambda s: values_of(s).get("invalid") == "1")
    assert level_of(status) == Level.ERROR
    values = values_of(status)
    assert (values["clipped_low"], values["clipped_high"], values["ok"]) == ("1", "1", "3")
    assert values["worst_1"].startswith("0 (row 0, col 0): INVALID")

    # stale temperature (timeout lowered to 0.5 s): the last good command is held, ERROR
    h.exchange(grid_to_msg(z))
    good = h.commands[-1]
    assert h.set_parameters(temperature_timeout=0.5).results[0].successful
    time.sleep(0.8)  # the scenario, not a wait for readiness: the estimate ages past 0.5 s
    np.testing.assert_array_equal(h.exchange(grid_to_msg(z * 0.5)), good)
    status = h.diagnostic("temperature", lambda s: level_of(s) == Level.ERROR)
    assert "stale" in status.message
    assert h.set_parameters(temperature_timeout=FRESH_S).results[0].successful
    # invalid temperature: held as well
    bad_T = TEMPERATURE.copy()
    bad_T[1, 1] = np.nan
    h.send_temperature(bad_T)
    np.testing.assert_array_equal(h.exchange(grid_to_msg(z * 0.5)), good)
    assert "non-finite" in h.diagnostic("temperature", lambda s: "non-finite" in s.message).message

    # run-time parameters: out of range and inconsistent sets are rejected with a reason
    h.send_temperature(TEMPERATURE)
    rejected = h.set_parameters(v_limit=5000.0)
    assert not rejected.results[0].successful
    assert "v_limit" in rejected.results[0].reason
    rejected = h.set_parameters(law__m2=[1.5e-15, 1.5e-15])
    assert not rejected.results[0].successful
    assert "law.m2" in rejected.results[0].reason
    # a valid change is swapped in for the next set point
    accepted = h.set_parameters(mode=Mode.INVERSE_QUADRATIC.value)
    assert accepted.results[0].successful
    command = h.exchange(grid_to_msg(z))
    np.testing.assert_allclose(quadratic_forward(command, TEMPERATURE, PARAMS), z, atol=1e-5 * NM)
    assert values_of(h.diagnostic("configuration"))["mode"] == "inverse_quadratic"
    # a new per-actuator map is taken as a whole
    scaled = (np.asarray(PARAMS.m2) * 1.1).ravel().tolist()
    assert h.set_parameters(law__m2=scaled).results[0].successful
    command = h.exchange(grid_to_msg(z))
    new_params = type(PARAMS)(**{**PARAMS.__dict__, "m2": np.asarray(PARAMS.m2) * 1.1})
    np.testing.assert_allclose(
        quadratic_forward(command, TEMPERATURE, new_params), z, atol=1e-5 * NM
    )
    assert proc.process.poll() is None
    assert proc.stop() == 0


def test_node_reports_not_ready_until_its_inputs_are_matched() -> None:
    args = ["--ros-args", "-p", "rows:=2", "-p", "cols:=3", "-p", "diagnostics_period:=0.2"]
    with (
        node_process("es_feedforward", "feedforward_node", args) as proc,
        ros_node("ff_ready_test") as node,
    ):
        seen: dict[str, DiagnosticStatus] = {}

        def on_diag(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if status.name == "feedforward: ready":
                    seen["ready"] = status

        def says(message: str) -> bool:
            return spin_until(node, lambda: "ready" in seen and seen["ready"].message == message,
                              20.0)  # fmt: skip

        node.create_subscription(DiagnosticArray, DIAGNOSTICS, on_diag, qos_for(DIAGNOSTICS))
        assert says("not ready: waiting for /dm/temperature, /dm/setpoint"), seen
        assert level_of(seen["ready"]) == Level.WARN
        node.create_publisher(Float64MultiArray, topics.TEMPERATURE, qos_for(topics.TEMPERATURE))
        assert says("not ready: waiting for /dm/setpoint"), seen
        node.create_publisher(Float64MultiArray, SETPOINT, qos_for(SETPOINT))
        assert says("ready"), seen
        assert level_of(seen["ready"]) == Level.OK
        # logged just after the status went out
        assert spin_until(node, lambda: "ready: every input matched" in proc.output(),
                          READY_TIMEOUT)
        assert proc.stop() == 0


def test_node_is_ready_only_once_its_command_publisher_matched_ready_subscribers() -> None:
    # A subscription matching the node's publisher is not the publisher matching it: the node
    # counts its own side, so a recorder it waits for gets the first command.
    args = ["--ros-args", "-p", "rows:=2", "-p", "cols:=3", "-p", "diagnostics_period:=0.2",
            "-p", "mode:=uncompensated", "-p", "ready_subscribers:=2"]
    with (
        node_process("es_feedforward", "feedforward_node", args) as proc,
        ros_node("ff_ready_out_test") as node,
    ):
        seen: dict[str, str] = {}

        def on_diag(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if status.name == "feedforward: ready":
                    seen["ready"] = status.message

        def says(message: str) -> bool:
            return spin_until(node, lambda: seen.get("ready") == message, READY_TIMEOUT)

        node.create_subscription(DiagnosticArray, DIAGNOSTICS, on_diag, qos_for(DIAGNOSTICS))
        node.create_publisher(Float64MultiArray, SETPOINT, qos_for(SETPOINT))
        assert says("not ready: waiting for /dm/command subscribers (0 of 2 matched)"), seen
        node.create_subscription(Float64MultiArray, COMMAND, lambda _m: None, qos_for(COMMAND))
        assert says("not ready: waiting for /dm/command subscribers (1 of 2 matched)"), seen
        node.create_subscription(Float64MultiArray, COMMAND, lambda _m: None, qos_for(COMMAND))
        assert says("ready"), seen
        assert proc.stop() == 0


def test_node_rejects_an_invalid_parameters_file_with_one_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(
        "feedforward:\n  ros__parameters:\n    rows: 2\n    cols: 2\n"
        "    law.m2: [1.0e-15, 2.0e-15, 3.0e-15]\n"
    )
    proc = NodeProcess(
        "es_feedforward", "feedforward_node", ["--ros-args", "--params-file", str(path)]
    )
    assert proc.process.wait(READY_TIMEOUT) == 2
    lines = [line for line in proc.output().splitlines() if line.strip()]
    assert lines[-1].startswith("error: ") and "law.m2" in lines[-1]
    assert "Traceback" not in proc.output()


@pytest.mark.parametrize(
    ("executor", "sig"),
    [("events", signal.SIGTERM), ("events", signal.SIGINT), ("single_threaded", signal.SIGTERM)],
)
def test_node_serves_and_stops_cleanly_on_either_executor(
    params_file: Path, executor: str, sig: int
) -> None:
    args = [
        "--ros-args", "--params-file", str(params_file), "-p", f"executor:={executor}",
        "-p", "diagnostics_period:=0.2",
    ]  # fmt: skip
    with (
        node_process("es_feedforward", "feedforward_node", args) as proc,
        ros_node("ff_test") as node,
    ):
        h = Harness(node)
        h.wait_connected(proc)
        z = np.full(SHAPE, 40.0 * NM)
        exchanges = 2  # the endpoints have matched: no estimate, no set point is lost
        for _ in range(exchanges):
            h.send_temperature(TEMPERATURE)
            command = h.exchange(grid_to_msg(z))
        np.testing.assert_allclose(
            hyperbolic_forward(command, TEMPERATURE, PARAMS), z, atol=1e-5 * NM
        )
        code = proc.stop(sig)
    assert code == 0, proc.output()
    # the clean-shutdown path ran: it logs what was published
    assert f"published /dm/command: {exchanges}" in proc.output(), proc.output()


def test_node_rejects_an_unknown_executor_with_one_line() -> None:
    proc = NodeProcess("es_feedforward", "feedforward_node", ["--ros-args", "-p", "executor:=fast"])
    assert proc.process.wait(READY_TIMEOUT) == 2
    lines = [line for line in proc.output().splitlines() if line.strip()]
    assert lines[-1].startswith("error: ") and "executor" in lines[-1], proc.output()


def test_node_reports_a_provisional_calibration_on_diagnostics(tmp_path: Path) -> None:
    path = tmp_path / "provisional.yaml"
    reasons = ["held-out error 3.6x the noise floor with structure left"]
    write_params_file(path, FeedforwardConfig(shape=SHAPE, params=PARAMS),
                      verdict=("provisional", reasons))
    args = ["--ros-args", "--params-file", str(path), "-p", "diagnostics_period:=0.2"]
    with (
        node_process("es_feedforward", "feedforward_node", args) as proc,
        ros_node("ff_verdict_test") as node,
    ):
        h = Harness(node)
        h.wait_connected(proc)
        status = h.diagnostic("calibration")
        assert level_of(status) == Level.WARN
        assert "provisional" in status.message and reasons[0] in status.message
        assert values_of(status)["verdict"] == "provisional"
        h.diagnostic("configuration")  # the other statuses are still there
