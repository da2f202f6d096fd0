"""The thermal node with self-sensing over DDS: readings fused per actuator, a bad one dropped."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from std_msgs.msg import Float64MultiArray
from support.ros import READY_TIMEOUT, NodeProcess, node_process, spin_until
from support.ros import test_node as ros_node

from es_msgs_py import topics
from es_msgs_py.arrays import grid_to_msg, msg_to_grid, sensors_to_msg
from es_msgs_py.diagnostics import Level, level_of

pytestmark = pytest.mark.dds

SHAPE = (4, 4)
F0 = 1.0e6 + 100.0 * np.arange(16)
A_T, A_V, T0 = 3227.0, -80.0, 40.0
VOLTS = 100.0


def test_node_fuses_resonance_and_drops_an_implausible_channel(tmp_path: Path) -> None:
    params = tmp_path / "thermal.yaml"
    params.write_text(
        yaml.safe_dump(
            {
                "thermal": {
                    "ros__parameters": {
                        "resonance.f0_hz": F0.tolist(),
                        "resonance.a_t_hz_per_degc": [A_T],
                        "resonance.a_v_hz_per_v": [A_V],
                        "resonance.reference_temperature": T0,
                        "resonance.noise_hz": 15.0,
                        "resonance.stale_after": 0.5,
                    }
                }
            }
        )
    )
    args = [
        "--ros-args", "--params-file", str(params),
        "-p", "rows:=4", "-p", "cols:=4", "-p", "sensor_pitch:=4",
        "-p", "time_scale:=0.05", "-p", "diagnostics_period:=0.2",
    ]  # fmt: skip
    truth = np.full(SHAPE, 40.0)
    truth[1, 1] = 41.0  # a warm actuator the single NTC cannot see
    estimates: list[np.ndarray] = []
    diagnostics: dict[str, DiagnosticStatus] = {}

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            diagnostics[status.name] = status

    with node_process("es_thermal", "thermal_node", args) as proc, ros_node("ss_test") as node:
        qos = topics.qos_for(topics.TEMPERATURE)
        sub = node.create_subscription(
            Float64MultiArray, topics.TEMPERATURE,
            lambda m: estimates.append(msg_to_grid(m, SHAPE)), qos,
        )  # fmt: skip
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diag, 10)
        pubs = {
            name: node.create_publisher(Float64MultiArray, name, topics.qos_for(name))
            for name in (topics.HEAT_LOAD, topics.RESONANCE, topics.COMMAND, topics.TEMPERATURE_RAW)
        }
        assert spin_until(
            node,
            lambda: all(p.get_subscription_count() > 0 for p in pubs.values())
            and sub.get_publisher_count() > 0,
            30.0,
        ), "thermal node never matched /dm/heat_load, /dm/resonance, /dm/command, raw and estimate"
        pubs[topics.HEAT_LOAD].publish(grid_to_msg(np.zeros(SHAPE)))
        rng = np.random.default_rng(1)
        for cycle in range(40):
            pubs[topics.COMMAND].publish(grid_to_msg(np.full(SHAPE, VOLTS)))
            freq = F0.reshape(SHAPE) + A_T * (truth - T0) + A_V * VOLTS
            freq = freq + 10.0 * rng.standard_normal(SHAPE)
            freq[2, 3] += 2.0e5  # channel 11 fails: 62 degC off
            freq[np.arange(16).reshape(SHAPE) % 2 != cycle % 2] = np.nan  # round robin
            pubs[topics.RESONANCE].publish(grid_to_msg(freq))
            wanted = len(estimates) + 1
            pubs[topics.TEMPERATURE_RAW].publish(sensors_to_msg(np.array([40.0])))
            got = spin_until(node, lambda n=wanted: len(estimates) >= n, READY_TIMEOUT)
            assert got, "no estimate"
        estimate = estimates[-1]
        assert estimate[1, 1] == pytest.approx(41.0, abs=0.05)
        others = np.ones(SHAPE, bool)
        others[1, 1] = False
        np.testing.assert_allclose(estimate[others], 40.0, atol=0.05)
        # a command published after the last sweep settles the command it ran under: the
        # last sweep (the odd channels, 11 among them) is fused and reported
        pubs[topics.COMMAND].publish(grid_to_msg(np.full(SHAPE, VOLTS)))
        name = "thermal: self-sensing"

        fused = ("sweeps_in_order", "sweeps_late", "sweeps_without_command")

        def reported() -> bool:  # the implausible channel and (nearly) every sweep fused
            status = diagnostics.get(name)
            if status is None:
                return False
            kv = {item.key: item.value for item in status.values}
            return "resonance_first_implausible" in kv and sum(
                int(kv.get(k, 0)) for k in fused
            ) >= 38

        assert spin_until(node, reported, READY_TIMEOUT), (
            f"no implausible channel in {diagnostics.get(name)}")
        status = diagnostics[name]
        values = {kv.key: kv.value for kv in status.values}
        assert level_of(status) == Level.WARN
        assert values["resonance_first_implausible"] == "11"
        # every sweep but the newest fused, with the command found by publication stamps (the
        # newest command only for a sweep that waited 1.5 periods after commands stopped)
        assert sum(int(values[k]) for k in fused) >= 38, values
        assert proc.process.poll() is None


def test_unusable_resonance_parameters_exit_with_one_line() -> None:
    args = [
        "--ros-args", "-p", "rows:=4", "-p", "cols:=4", "-p", "sensor_pitch:=4",
        "-p", "resonance.f0_hz:=[1000000.0, 1000000.0, 1000000.0]",
    ]  # fmt: skip
    proc = NodeProcess("es_thermal", "thermal_node", args)
    try:
        proc.process.wait(60.0)
    finally:
        code = proc.stop()
    lines = [line for line in proc.output().splitlines() if line.strip()]
    assert code == 2, proc.output()
    assert "resonance.f0_hz has 3 values, expected 1 or 16" in lines[-1]
    assert "Traceback" not in proc.output()


def test_self_sensing_on_the_events_executor_exits_with_one_line() -> None:
    # the self-sensing callbacks need the message info, which the EventsExecutor does not pass
    args = [
        "--ros-args", "-p", "rows:=4", "-p", "cols:=4", "-p", "sensor_pitch:=4",
        "-p", f"resonance.f0_hz:={F0.tolist()}", "-p", "executor:=events",
    ]  # fmt: skip
    proc = NodeProcess("es_thermal", "thermal_node", args)
    try:
        proc.process.wait(60.0)
    finally:
        code = proc.stop()
    lines = [line for line in proc.output().splitlines() if line.strip()]
    assert code == 2, proc.output()
    assert lines[-1].startswith("error: executor=events cannot run self-sensing"), lines[-1]
    assert "Traceback" not in proc.output()
