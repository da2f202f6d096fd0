"""The plant node over DDS: lockstep protocol, bad commands rejected and held, clean exit."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray
from support import ros

from es_msgs_py import topics
from es_msgs_py.arrays import grid_to_msg, msg_to_grid, sensors_to_msg
from es_msgs_py.diagnostics import Level, level_of, make_array, readiness_status
from es_physics.laws import hyperbolic_forward
from es_physics.params import ActuatorParams

pytestmark = pytest.mark.dds

SCENARIO = """
name: node_test
grid: {rows: 2, cols: 2}
control_rate: 100.0
sensor_rate: 10.0
duration: 1.0
base_temperature: {points: [[0, 45.0]]}
sensors: {noise_sd: 0.0, resolution: 0.0}
actuators: {spread: {}}
setpoint:
  offset: 50.0e-9
  sine: {amplitude: 20.0e-9, frequency: 2.0}
"""
#: Best effort like the /clock publisher, with room so that a busy test process loses none.
CLOCK_LISTENER_QOS = QoSProfile(depth=500, reliability=ReliabilityPolicy.BEST_EFFORT)
BAD_FROM = 60  # set points from this step on are answered with bad commands
SILENT_STEP = 80  # this set point gets no answer: the plant times out and holds


def bad_command(step: int) -> Float64MultiArray:
    """A rotating choice of invalid commands."""
    kind = step % 3
    if kind == 0:
        return grid_to_msg(np.full((2, 2), np.nan))
    if kind == 1:
        return sensors_to_msg(np.full(4, 50.0))  # wrong layout
    return grid_to_msg(np.full((2, 2), 400.0))  # beyond the amplifier limit


def test_lockstep_run_with_echo_source_rejects_and_holds(tmp_path: Path) -> None:
    scenario = tmp_path / "node_test.yaml"
    scenario.write_text(SCENARIO)
    args = [
        "--ros-args",
        "-p", f"scenario:={scenario}",
        "-p", "sync_temperature:=false",
        "-p", "exit_when_done:=true",
        "-p", "command_timeout:=3.0", "-p", "start_timeout:=60.0",
    ]  # fmt: skip
    # 3 s: the one silent step costs that; no answer of a busy test process takes that long
    with ros.test_node("plant_echo") as node:
        commands: list[np.ndarray] = []
        displacements: list[np.ndarray] = []
        clocks: list[float] = []
        raw: list[np.ndarray] = []
        warn_values: list[dict[str, str]] = []
        publishers: list[Publisher] = []  # created once the listeners have matched

        def on_setpoint(msg: Float64MultiArray) -> None:
            step = len(commands)
            setpoint = msg_to_grid(msg, (2, 2))
            commands.append(setpoint * 1.0e9)  # 50 nm -> 50 V: valid and recognisable
            if step == SILENT_STEP:
                return
            reply = grid_to_msg(commands[-1]) if step < BAD_FROM else bad_command(step)
            publishers[0].publish(reply)

        def on_diagnostics(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if status.name == "plant: commands" and level_of(status) == Level.WARN:
                    warn_values.append({kv.key: kv.value for kv in status.values})

        qos = topics.DM_QOS
        listeners = [
            node.create_subscription(Float64MultiArray, topics.SETPOINT, on_setpoint, qos),
            node.create_subscription(
                Float64MultiArray,
                topics.DISPLACEMENT,
                lambda m: displacements.append(msg_to_grid(m, (2, 2))),
                qos,
            ),
            node.create_subscription(
                Float64MultiArray, topics.TEMPERATURE_RAW, lambda m: raw.append(m.data), qos
            ),
            node.create_subscription(
                Clock,
                topics.CLOCK,
                lambda m: clocks.append(m.clock.sec + m.clock.nanosec * 1e-9),
                CLOCK_LISTENER_QOS,
            ),
            node.create_subscription(
                DiagnosticArray, topics.DIAGNOSTICS, on_diagnostics, topics.DIAGNOSTICS_QOS
            ),
        ]
        with ros.node_process("es_sim_plant", "plant_node", args) as plant:
            # The plant steps once a command source has matched: be that source only when
            # every listener has matched the plant, so that no message goes unseen.
            ros.wait_matched(node, listeners, processes=[plant])
            publishers.append(node.create_publisher(Float64MultiArray, topics.COMMAND, qos))
            assert ros.spin_until(node, lambda: plant.process.poll() is not None,
                                  timeout=ros.READY_TIMEOUT), "the plant did not finish its run"
            ros.spin_until(node, lambda: len(displacements) >= 101, timeout=ros.READY_TIMEOUT)
            assert plant.process.returncode == 0, plant.output()
            log = plant.output()

    assert len(commands) == 100
    assert len(displacements) == 101  # z(t_0) .. z(t_100)
    assert len(raw) == 10
    # /clock is best effort (as rclpy's time source expects): every tick received is a step
    # time t_k = k / 100, increasing, up to t_100 = 1 s.
    ticks = np.round(np.asarray(clocks) * 100.0)
    np.testing.assert_allclose(np.asarray(clocks) * 100.0, ticks, atol=1e-6)
    assert len(clocks) > 50 and np.all(np.diff(ticks) > 0) and 95 <= ticks[-1] <= 100
    # Displacement k+1 answers the command of step k (thesis parameters, 45 degC, no spread).
    for k in range(BAD_FROM):
        expected = hyperbolic_forward(commands[k], 45.0, ActuatorParams())
        np.testing.assert_allclose(displacements[k + 1], expected, rtol=1e-9)
    # From then on the last valid command is held: the displacement stays put.
    for k in range(BAD_FROM, 100):
        np.testing.assert_allclose(displacements[k + 1], displacements[BAD_FROM], rtol=1e-12)
    assert "command rejected" in log
    assert "finished" in log
    assert warn_values, "no WARN diagnostic for rejected commands"
    final = warn_values[-1]
    assert int(final["rejected"]) >= 1
    assert "command_timeouts 1" in log
    assert "rejected 39" in log


class StandIns:
    """Thermal node and feedforward stand-ins: an estimate per raw sample, a command per set
    point (10^9 V per m), noting how many estimates had gone out at each set point."""

    def __init__(self, node: Node) -> None:
        qos = topics.DM_QOS
        self.node = node
        self.publishers: dict[str, Publisher] = {}  # created once the listeners have matched
        self.replies = 0
        self.replies_seen_at_setpoint: list[int] = []
        self.listeners = [
            node.create_subscription(Float64MultiArray, topics.TEMPERATURE_RAW, self._on_raw, qos),
            node.create_subscription(Float64MultiArray, topics.SETPOINT, self._on_setpoint, qos),
            # the plant waits for a thermal node's heat-load subscription as well
            node.create_subscription(Float64MultiArray, topics.HEAT_LOAD, lambda _m: None, qos),
        ]

    def _on_raw(self, msg: Float64MultiArray) -> None:
        estimate = grid_to_msg(np.full((2, 2), float(msg.data[0])))
        self.publishers[topics.TEMPERATURE].publish(estimate)
        self.replies += 1

    def _on_setpoint(self, msg: Float64MultiArray) -> None:
        self.replies_seen_at_setpoint.append(self.replies)
        command = grid_to_msg(msg_to_grid(msg, (2, 2)) * 1.0e9)
        self.publishers[topics.COMMAND].publish(command)

    def connect(self, plant: ros.NodeProcess) -> None:
        """Wait for the plant's outputs to match, then publish estimates and commands."""
        ros.wait_matched(self.node, self.listeners, processes=[plant])
        for topic in (topics.TEMPERATURE, topics.COMMAND):
            self.publishers[topic] = self.node.create_publisher(
                Float64MultiArray, topic, topics.DM_QOS
            )
        ros.wait_matched(self.node, list(self.publishers.values()), processes=[plant])


def test_sync_temperature_barrier_orders_setpoints_after_estimates(tmp_path: Path) -> None:
    scenario = tmp_path / "node_test.yaml"
    scenario.write_text(SCENARIO.replace("duration: 1.0", "duration: 0.3"))
    # bounds far beyond an answer's time on a loaded machine: a timeout here is a failure
    args = ["--ros-args", "-p", f"scenario:={scenario}", "-p", "exit_when_done:=true",
            "-p", "start_timeout:=60.0", "-p", "command_timeout:=30.0",
            "-p", "sync_timeout:=30.0"]  # fmt: skip
    with ros.test_node("plant_sync") as node:
        stand_ins = StandIns(node)
        with ros.node_process("es_sim_plant", "plant_node", args) as plant:
            stand_ins.connect(plant)
            ros.spin_until(node, lambda: plant.process.poll() is not None, timeout=60.0)
            assert plant.process.returncode == 0, plant.output()
            log = plant.output()
    # Step k's set point comes only after the estimate answering step k's sample (k = 0, 10, 20).
    assert stand_ins.replies_seen_at_setpoint == [k // 10 + 1 for k in range(30)]
    assert "sync_timeouts 0" in log and "command_timeouts 0" in log


def test_first_step_waits_for_raw_subscribers_controller_subscriptions(tmp_path: Path) -> None:
    # In lockstep the feedforward counts the raw samples too: the graph asks for two.
    scenario = tmp_path / "node_test.yaml"
    scenario.write_text(SCENARIO.replace("duration: 1.0", "duration: 0.1"))
    args = ["--ros-args", "-p", f"scenario:={scenario}", "-p", "exit_when_done:=true",
            "-p", "start_timeout:=60.0", "-p", "command_timeout:=30.0",
            "-p", "sync_timeout:=30.0", "-p", "raw_subscribers:=2"]  # fmt: skip
    with ros.test_node("plant_raw_subs") as node:
        stand_ins = StandIns(node)
        with ros.node_process("es_sim_plant", "plant_node", args) as plant:
            stand_ins.connect(plant)
            ros.spin_until(node, lambda: False, 1.5)  # the scenario: one raw subscriber only
            assert not stand_ins.replies_seen_at_setpoint, plant.output()
            node.create_subscription(Float64MultiArray, topics.TEMPERATURE_RAW,
                                     lambda _m: None, topics.DM_QOS)  # fmt: skip
            assert ros.spin_until(node, lambda: plant.process.poll() is not None, 60.0)
            assert plant.process.returncode == 0, plant.output()
    assert len(stand_ins.replies_seen_at_setpoint) == 10


def test_first_step_waits_for_the_nodes_it_is_told_to_wait_for(tmp_path: Path) -> None:
    scenario = tmp_path / "node_test.yaml"
    scenario.write_text(SCENARIO.replace("duration: 1.0", "duration: 0.2"))
    args = [
        "--ros-args", "-p", f"scenario:={scenario}", "-p", "exit_when_done:=true",
        "-p", "sync_temperature:=false", "-p", 'wait_ready:=["feedforward", "record"]',
        "-p", "start_timeout:=60.0",
    ]  # fmt: skip
    with ros.test_node("plant_ready") as node:
        commands = node.create_publisher(Float64MultiArray, topics.COMMAND, topics.DM_QOS)
        diagnostics = node.create_publisher(
            DiagnosticArray, topics.DIAGNOSTICS, topics.qos_for(topics.DIAGNOSTICS)
        )
        setpoints: list[int] = []

        def on_setpoint(msg: Float64MultiArray) -> None:
            setpoints.append(1)
            commands.publish(grid_to_msg(msg_to_grid(msg, (2, 2)) * 1.0e9))

        def report(ready: set[str]) -> None:
            statuses = [readiness_status(name, [] if name in ready else ["/dm/temperature"])
                        for name in ("feedforward", "record")]  # fmt: skip
            diagnostics.publish(make_array(node.get_clock().now().to_msg(), statuses))

        node.create_subscription(Float64MultiArray, topics.SETPOINT, on_setpoint, topics.DM_QOS)
        with ros.node_process("es_sim_plant", "plant_node", args) as plant:
            assert ros.spin_until(node, lambda: diagnostics.get_subscription_count() > 0, 30.0)
            for ready in (set(), {"feedforward"}):  # not all ready: no step
                deadline = time.monotonic() + 1.5
                while time.monotonic() < deadline:
                    report(ready)
                    ros.spin_until(node, lambda: False, 0.1)
                assert not setpoints, plant.output()
            report({"feedforward", "record"})
            assert ros.spin_until(node, lambda: plant.process.poll() is not None, 60.0)
            assert plant.process.returncode == 0, plant.output()
    assert len(setpoints) == 20


def test_a_node_that_never_says_ready_is_named_when_the_start_times_out(
    tmp_path: Path,
) -> None:
    scenario = tmp_path / "node_test.yaml"
    scenario.write_text(SCENARIO.replace("duration: 1.0", "duration: 0.05"))
    args = [
        "--ros-args", "-p", f"scenario:={scenario}", "-p", "exit_when_done:=true",
        "-p", "sync_temperature:=false", "-p", "publish_setpoints:=false",
        "-p", 'wait_ready:=["thermal"]', "-p", "start_timeout:=1.0",
    ]  # fmt: skip
    with ros.node_process("es_sim_plant", "plant_node", args) as plant:
        plant.process.wait(60)
        output = plant.output()
    assert plant.process.returncode == 0, output
    assert "(not ready: thermal); stepping anyway" in output


def test_real_time_mode_runs_on_the_wall_clock(tmp_path: Path) -> None:
    scenario = tmp_path / "node_test.yaml"
    scenario.write_text(SCENARIO.replace("duration: 1.0", "duration: 2.0"))
    # No controller comes: the plant waits start_timeout for one, then runs on its own.
    args = [
        "--ros-args", "-p", f"scenario:={scenario}", "-p", "lockstep:=false",
        "-p", "exit_when_done:=true", "-p", "start_timeout:=6.0",
    ]  # fmt: skip
    # 6 s: the test's /clock subscription matches well before the 2 s run ends, even when
    # discovery takes seconds on a loaded machine
    with ros.test_node("plant_rt") as node:
        clocks: list[float] = []
        subscription = node.create_subscription(
            Clock,
            topics.CLOCK,
            lambda m: clocks.append(m.clock.sec + m.clock.nanosec * 1e-9),
            CLOCK_LISTENER_QOS,
        )
        with ros.node_process("es_sim_plant", "plant_node", args) as plant:
            ros.wait_matched(node, [subscription], processes=[plant])
            ros.spin_until(node, lambda: plant.process.poll() is not None, timeout=60.0)
            assert plant.process.returncode == 0, plant.output()
            log = plant.output()
    assert "real time" in log
    assert "peers not all present after 6 s" in log
    # The wall timer paces it (200 steps of 10 ms): never faster than real time (how much
    # slower depends on the machine's load: no bound here)
    speed = float(log.split("x real time")[0].rsplit("(", 1)[1])
    assert 0.0 < speed < 1.05
    # A subscriber matched before the plant ended sees the clock advance up to the end (2 s).
    assert clocks, "no /clock message received after the subscription matched"
    assert 1.0 <= max(clocks) <= 2.0 + 1e-9


@pytest.mark.parametrize(
    ("param", "reason"),
    [("scenario:=no_such_scenario", "unknown scenario"), ("rows:=-3", "out of range")],
)
def test_bad_parameters_exit_2_with_one_line(param: str, reason: str) -> None:
    with ros.node_process("es_sim_plant", "plant_node", ["--ros-args", "-p", param]) as plant:
        plant.process.wait(ros.READY_TIMEOUT)
        output = plant.output()
    assert plant.process.returncode == 2
    errors = [line for line in output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and reason in errors[0]
    assert "Traceback" not in output
