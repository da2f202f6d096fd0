"""es_node_runtime.node_main: the executor choice (parameter, both executors, fallback) and the
bounded teardown."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
import rclpy.experimental
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from support.ros import test_node as ros_node

from es_node_runtime.node_main import (
    EXECUTOR_PARAMETER,
    EXECUTORS,
    executor_kind,
    spin,
    usage_text,
    wants_help,
)
from es_node_runtime.params import ParameterSpec, declare_parameters

pytestmark = pytest.mark.dds


def _spin_until_a_timer_shuts_down(node: Node, kind: str) -> int:
    """Spin ``node`` on ``kind``; a 20 ms timer counts and shuts the context down at 3."""
    fired = 0

    def tick() -> None:
        nonlocal fired
        fired += 1
        if fired == 3:
            node.context.try_shutdown()

    node.create_timer(0.02, tick)
    with contextlib.suppress(ExternalShutdownException):
        spin(node, kind)
    return fired


def test_a_node_without_the_parameter_gets_the_single_threaded_executor() -> None:
    with ros_node("plain") as node:
        assert executor_kind(node) == "single_threaded"


def test_the_parameter_names_the_executor() -> None:
    with ros_node("chooser") as node:
        spec = ParameterSpec(EXECUTOR_PARAMETER, "events", "Executor.", choices=EXECUTORS)
        declare_parameters(node, [spec])
        assert executor_kind(node) == "events"


@pytest.mark.parametrize("kind", EXECUTORS)
def test_each_executor_runs_timers_and_returns_when_the_context_shuts_down(kind: str) -> None:
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(f"spin_{kind}", context=context)
    try:
        assert _spin_until_a_timer_shuts_down(node, kind) == 3
    finally:
        node.destroy_node()
        context.try_shutdown()


def test_events_falls_back_to_single_threaded_without_the_events_executor(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delattr(rclpy.experimental, "EventsExecutor")
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("fallback", context=context)
    try:
        assert _spin_until_a_timer_shuts_down(node, "events") == 3
    finally:
        node.destroy_node()
        context.try_shutdown()


# A node whose teardown never returns, as a Fast DDS participant teardown can hang.
HANGING_TEARDOWN = r"""
import sys, time
from rclpy.node import Node
from es_node_runtime.node_main import run_node

class HangsInTeardown(Node):
    def __init__(self):
        super().__init__("hangs_in_teardown")
        self.create_timer(0.05, self.context.try_shutdown)

    def destroy_node(self):
        time.sleep(60)

sys.exit(run_node(HangsInTeardown, [], teardown_limit=0.5))
"""


def test_a_hanging_teardown_ends_the_process_with_exit_1_and_its_stack() -> None:
    done = subprocess.run(
        [sys.executable, "-c", HANGING_TEARDOWN],
        capture_output=True,
        text=True,
        timeout=30,  # far below the 60 s the teardown would hang
        check=False,
    )
    assert done.returncode == 1, done.stderr
    assert "Timeout (0:00:00.500000)!" in done.stderr
    assert "in destroy_node" in done.stderr


# Ctrl-C while the node is still being built: rclpy's handler shuts the context down and the
# constructor's next rcl call fails ("context is invalid").
STOPPED_WHILE_BUILT = r"""
import sys
import rclpy
from rclpy.node import Node
from es_node_runtime.node_main import run_node

class StoppedWhileBuilt(Node):
    def __init__(self):
        super().__init__("stopped_while_built")
        rclpy.shutdown()  # what the SIGINT handler does
        self.create_timer(0.05, lambda: None)

sys.exit(run_node(StoppedWhileBuilt, []))
"""


def test_a_stop_while_the_node_is_built_is_a_clean_exit() -> None:
    done = subprocess.run(
        [sys.executable, "-c", STOPPED_WHILE_BUILT],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
# A node that reports, at close() and destroy_node(), whether its context is still valid.
STOPPED_BY_SIGNAL = r"""
import sys
from rclpy.node import Node
from es_node_runtime.node_main import run_node

class Reports(Node):
    def __init__(self):
        super().__init__("reports_its_stop")
        self.timer = self.create_timer(0.02, self.spinning)

    def spinning(self):
        print("spinning", flush=True)
        self.timer.cancel()

    def close(self):
        print(f"close: context ok {self.context.ok()}", flush=True)

    def destroy_node(self):
        print(f"destroy_node: context ok {self.context.ok()}", flush=True)
        super().destroy_node()

sys.exit(run_node(Reports, []))
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_closes_and_destroys_the_node_before_the_context_shuts_down(
    sig: int,
) -> None:
    # rclpy's own handlers would shut the context down from their thread at the signal,
    # concurrently with close() (a SIGSEGV now and then): close and destroy see it valid.
    proc = subprocess.Popen([sys.executable, "-c", STOPPED_BY_SIGNAL], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert first == "spinning\n", first + proc.stdout.read()
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    said = [line for line in out.splitlines() if line.startswith(("close", "destroy_node"))]
    assert said == ["close: context ok True", "destroy_node: context ok True"], out


# A node that says, while it spins, whether its start-up's objects are frozen.
REPORTS_FROZEN = r"""
import gc
import sys
from rclpy.node import Node
from es_node_runtime.node_main import run_node

class Frozen(Node):
    def __init__(self):
        super().__init__("reports_frozen")
        self.create_timer(0.02, self.spinning)

    def spinning(self):
        print(f"frozen {gc.get_freeze_count()}, garbage {len(gc.garbage)}", flush=True)
        self.context.try_shutdown()

sys.exit(run_node(Frozen, []))
"""


def test_the_node_spins_with_its_start_up_objects_frozen_out_of_the_collector() -> None:
    done = subprocess.run([sys.executable, "-c", REPORTS_FROZEN], capture_output=True,
                          text=True, timeout=60, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    line = next(x for x in done.stdout.splitlines() if x.startswith("frozen"))
    frozen = int(line.split()[1].rstrip(","))
    assert frozen > 10_000, line  # rclpy, numpy, the node: tens of thousands of objects
    assert line.endswith("garbage 0"), line


@pytest.mark.parametrize(
    ("package", "name"),
    [
        ("es_sim_plant", "plant_node"), ("es_thermal", "thermal_node"),
        ("es_feedforward", "feedforward_node"), ("es_recordings", "record"),
        ("es_calibration", "calibrate"), ("es_bringup", "bringup"), ("es_bringup", "demo"),
    ],
)  # fmt: skip
def test_every_executable_answers_help_without_starting_a_node(package: str, name: str) -> None:
    launcher = Path(sys.prefix) / "lib" / package / name
    # an invalid domain: a node that started anyway would fail loudly
    env = dict(os.environ, ROS_DOMAIN_ID="999")
    # a bound for a hang, not a timing: ``demo --help`` took 40 s at load average 22 here
    result = subprocess.run([str(launcher), "--help"], capture_output=True, text=True,
                            timeout=180, env=env, check=False)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "usage" in result.stdout.lower()
    assert "[INFO]" not in result.stdout + result.stderr


def test_help_lists_every_parameter_with_its_description() -> None:
    specs = [ParameterSpec("v_limit", 350.0, "Amplifier limit [V].", 1.0, 1000.0),
             ParameterSpec("mode", "a", "Scheme: 'a': first; 'b': second.", choices=("a", "b"))]
    text = usage_text("pkg node_exe", "Does things.", specs)
    assert text.startswith("usage: ros2 run pkg node_exe")
    assert "  v_limit (350.0): Amplifier limit [V]." in text
    assert "'b': second. One of: a, b." in text
    assert wants_help(["node", "--help"]) and wants_help(["node", "-h", "--ros-args"])
    assert not wants_help(["node", "--ros-args", "-p", "x:=--help"])
