"""The plant node's /dm/resonance over DDS: published only when switched on, round robin."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray
from support import ros

from es_msgs_py import topics
from es_msgs_py.arrays import msg_to_grid

pytestmark = pytest.mark.dds

SCENARIO = """
name: resonance_test
grid: {rows: 3, cols: 4}
control_rate: 100.0
sensor_rate: 10.0
duration: 60.0
base_temperature: {points: [[0, 45.0]]}
resonance: {group_size: 4}
"""


@pytest.mark.parametrize("switched_on", [True, False])
def test_plant_publishes_sweeps_only_when_switched_on(tmp_path: Path, switched_on: bool) -> None:
    scenario = tmp_path / "resonance_test.yaml"
    scenario.write_text(SCENARIO)
    args = [
        "--ros-args", "-p", f"scenario:={scenario}", "-p", "lockstep:=false",
        "-p", f"resonance:={'true' if switched_on else 'false'}",
    ]  # fmt: skip
    sweeps: list[np.ndarray] = []
    with ros.test_node("resonance_listener") as node:
        node.create_subscription(
            Float64MultiArray, topics.RESONANCE,
            lambda m: sweeps.append(msg_to_grid(m, (3, 4))), topics.qos_for(topics.RESONANCE),
        )  # fmt: skip
        raw = node.create_subscription(
            Float64MultiArray, topics.TEMPERATURE_RAW, lambda _m: None,
            topics.qos_for(topics.TEMPERATURE_RAW),
        )  # fmt: skip
        with ros.node_process("es_sim_plant", "plant_node", args) as plant:
            assert ros.spin_until(node, lambda: raw.get_publisher_count() > 0,
                                  ros.READY_TIMEOUT), (
                "plant never published /dm/temperature/raw"
            )
            if switched_on:
                got = ros.spin_until(node, lambda: len(sweeps) >= 6, ros.READY_TIMEOUT)
                assert got, plant.output()
            else:  # the plant's publishers are on the graph: none for /dm/resonance
                assert node.count_publishers(topics.RESONANCE) == 0
                assert plant.process.poll() is None
    if not switched_on:
        assert sweeps == []
        return
    swept = np.array([np.isfinite(s) for s in sweeps[:6]])
    assert np.all(swept.sum(axis=(1, 2)) == 4)  # one group of 4 per sample
    # consecutive samples sweep different groups; three samples cover the grid
    for start in range(len(swept) - 2):
        np.testing.assert_array_equal(swept[start : start + 3].sum(axis=0), np.ones((3, 4)))
    values = np.concatenate([s[np.isfinite(s)] for s in sweeps])
    assert np.all(np.abs(values - 1.0e6 - 3227.0 * 5.0) < 30e3)  # near f0 + a_T (45 - 40)
