"""The feedforward node in lockstep (``sync_temperature``): a set point that arrives before
the estimate of a raw sample sent ahead of it waits for that estimate (bounded).

The lockstep plant sends a step's raw sample, waits for the estimate, then sends the set
point; the estimate comes from another publisher, so under load the set point can reach
the feedforward first. Here the test node plays the plant and the thermal node and sends
them in exactly that bad order.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray
from support.ros import READY_TIMEOUT, NodeProcess, node_process, spin_until, wait_matched
from support.ros import test_node as ros_node

from es_feedforward.feedforward import FeedforwardConfig
from es_feedforward.param_file import write_params_file
from es_msgs_py import topics
from es_msgs_py.arrays import grid_to_msg
from es_msgs_py.diagnostics import Level, level_of
from es_physics.laws import hyperbolic_forward

from .test_feedforward_node import FRESH_S, NM, PARAMS, SHAPE, TEMPERATURE, Harness, values_of

pytestmark = pytest.mark.dds

Z = np.array([[10.0, 50.0, 90.0], [120.0, 60.0, 5.0]]) * NM
#: A second estimate, far enough from TEMPERATURE that a command for one misses z on the other.
WARMER = TEMPERATURE + 5.0
#: How long the set point is left alone before its estimate is sent: a wait that did not
#: happen shows as a command computed with the old estimate.
HOLD_S = 0.5


class PlantLike(Harness):
    """The harness plus the plant's raw-sample publisher."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.raw = self.node.create_publisher(
            Float64MultiArray, topics.TEMPERATURE_RAW, topics.qos_for(topics.TEMPERATURE_RAW)
        )

    def wait_connected(self, proc: NodeProcess) -> None:
        """Wait for our endpoints' matches and the node's own ready (its command writer
        matched our subscription), so no message of the test is lost to start-up."""
        endpoints = [self.setpoint, self.temperature, self.raw, self.command_sub, self.diag_sub]
        wait_matched(self.node, endpoints, processes=[proc])
        self.diagnostic("ready", lambda s: level_of(s) == Level.OK)

    def step(self, estimate: np.ndarray) -> np.ndarray:
        """One lockstep step in the plant's order: raw sample, its estimate, the set point."""
        self.raw.publish(grid_to_msg(np.zeros(SHAPE)))
        self.send_temperature(estimate)
        return self.exchange(grid_to_msg(Z))


@contextmanager
def _start(
    tmp_path: Path, executor: str, sync_timeout: float
) -> Iterator[tuple[PlantLike, NodeProcess]]:
    path = tmp_path / "feedforward.yaml"
    write_params_file(path, FeedforwardConfig(shape=SHAPE, params=PARAMS,
                                              temperature_timeout=FRESH_S))
    args = [
        "--ros-args", "--params-file", str(path), "-p", f"executor:={executor}",
        "-p", "diagnostics_period:=0.2", "-p", "ready_subscribers:=1",
        "-p", "sync_temperature:=true", "-p", f"sync_timeout:={sync_timeout}",
    ]  # fmt: skip
    with (
        node_process("es_feedforward", "feedforward_node", args) as proc,
        ros_node("ff_sync_test") as node,
    ):
        h = PlantLike(node)
        h.wait_connected(proc)
        yield h, proc


def _hit(command: np.ndarray, estimate: np.ndarray) -> bool:
    return bool(np.allclose(hyperbolic_forward(command, estimate, PARAMS), Z, atol=1e-5 * NM))


@pytest.mark.parametrize("executor", ["events", "single_threaded"])
def test_set_point_waits_for_the_estimate_of_an_earlier_raw_sample(
    tmp_path: Path, executor: str
) -> None:
    # a wait that cannot time out on a loaded machine: only the ordering is under test
    with _start(tmp_path, executor, sync_timeout=60.0) as (h, proc):
        assert _hit(h.step(TEMPERATURE), TEMPERATURE)
        before = len(h.commands)
        # the bad order: the step's raw sample, its set point, and only then its estimate
        h.raw.publish(grid_to_msg(np.zeros(SHAPE)))
        h.setpoint.publish(grid_to_msg(Z))
        spin_until(h.node, lambda: len(h.commands) > before, HOLD_S)
        assert len(h.commands) == before, "the set point did not wait for its estimate"
        h.temperature.publish(grid_to_msg(WARMER))
        assert spin_until(h.node, lambda: len(h.commands) > before, READY_TIMEOUT)
        assert _hit(h.commands[-1], WARMER), "computed with the previous estimate"
        assert not _hit(h.commands[-1], TEMPERATURE)
        status = h.diagnostic(
            "temperature", lambda s: values_of(s).get("setpoints_waited_for_estimate") == "1"
        )
        assert values_of(status)["estimates_timed_out"] == "0"
        # in order again: no wait, one command per set point
        assert _hit(h.step(TEMPERATURE), TEMPERATURE)
        assert len(h.commands) == before + 2
        assert proc.stop() == 0
    assert "set points that waited for their estimate 1, estimates timed out 0" in proc.output()


def test_an_estimate_that_never_comes_ends_the_wait_after_sync_timeout(tmp_path: Path) -> None:
    with _start(tmp_path, "events", sync_timeout=0.5) as (h, proc):
        assert _hit(h.step(TEMPERATURE), TEMPERATURE)
        h.raw.publish(grid_to_msg(np.zeros(SHAPE)))  # e.g. a sample the thermal node rejected
        started = time.monotonic()
        command = h.exchange(grid_to_msg(Z))  # answered, with the newest estimate
        assert time.monotonic() - started >= 0.3  # it did wait (less the raw's transit)
        assert _hit(command, TEMPERATURE)
        status = h.diagnostic(
            "temperature", lambda s: values_of(s).get("estimates_timed_out") == "1"
        )
        assert values_of(status)["setpoints_waited_for_estimate"] == "1"
        assert proc.stop() == 0
    assert "no /dm/temperature within sync_timeout" in proc.output()
    assert "estimates timed out 1, set points still waiting at the stop (no command) 0" in (
        proc.output()
    )


@pytest.mark.parametrize("bad", ["wrong length", "non-finite"])
def test_a_bad_estimate_ends_the_wait_and_never_reaches_the_command(
    tmp_path: Path, bad: str
) -> None:
    # the thermal node's answer to the raw sample is unusable: the waiting set point must be
    # answered at once (the estimate came), never from the bad values
    estimate = Float64MultiArray(data=[45.0] * 5) if bad == "wrong length" else grid_to_msg(
        np.full(SHAPE, np.nan)
    )
    with _start(tmp_path, "events", sync_timeout=60.0) as (h, proc):
        good = h.step(TEMPERATURE)
        before = len(h.commands)
        h.raw.publish(grid_to_msg(np.zeros(SHAPE)))
        h.setpoint.publish(grid_to_msg(Z / 2))
        spin_until(h.node, lambda: len(h.commands) > before, HOLD_S)
        assert len(h.commands) == before, "the set point did not wait for its estimate"
        h.temperature.publish(estimate)
        assert spin_until(h.node, lambda: len(h.commands) > before, READY_TIMEOUT)
        command = h.commands[-1]
        assert np.all(np.isfinite(command))
        if bad == "wrong length":  # rejected at the door: the last good estimate still holds
            assert np.allclose(hyperbolic_forward(command, TEMPERATURE, PARAMS), Z / 2,
                               atol=1e-5 * NM)
        else:  # a NaN estimate invalidates the temperature: the last good command is held
            assert np.array_equal(command, good)
        status = h.diagnostic(
            "temperature", lambda s: values_of(s).get("setpoints_waited_for_estimate") == "1"
        )
        assert values_of(status)["estimates_timed_out"] == "0"
        assert proc.stop() == 0
    assert "set points that waited for their estimate 1, estimates timed out 0" in proc.output()
