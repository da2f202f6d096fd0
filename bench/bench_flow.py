"""Lossless set points at 1 kHz x 4096: the source paced on the node's acknowledgement.

Usage (from the repository root, after ./scripts/bootstrap)::

    .venv/bin/python bench/bench_flow.py [--seconds 10] [--rate 1000] [--window 32] [--shape 64 64]

The feedforward node (``--shape``, default 64 x 64 = 4096 actuators) and a recorder of
/dm/setpoint and /dm/command run as processes; a client in this process publishes set points
at ``--rate`` for ``--seconds``, first on an idle machine, then beside two CPU hogs
(bench/common/load.py). Flow control (docs/architecture.md "QoS"): the client never has more than
``--window`` set points without their command, and at most RECORDER_WINDOW set points or
commands that the recorder has not reported received (it reports every REPORT_PERIOD_S on
/diagnostics); a set point that is due while a window is full waits, and is counted as
``held back`` (per window: node or recorder) with the time it waited. The stream is then as
fast as the slower of node and recorder serves it, at most ``--rate``, and nothing is lost:
published == received == recorded, for set points and commands alike.

Readiness is a fact: the node is started with ``ready_subscribers:=2`` (the client and the
recorder), so its "ready" log line says that its command publisher has matched both; the
client waits for its own set-point publisher to have matched the node and the recorder.
:func:`flow_runs` returns one :class:`FlowRun` per condition; ``main`` prints them as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from es_msgs_py.topic_names import DM_DEPTH

#: Longest wait [s] for readiness, for the last commands, and for a process to stop.
READY_S = 120.0
DRAIN_S = 60.0
STOP_S = 30.0
#: Set points without a command at most (flow control); far below the /dm history depth.
DEFAULT_WINDOW = 32
#: Messages per topic the recorder may not yet have reported received: half the history
#: depth, so that neither the node's writer nor the recorder's reader can overflow.
RECORDER_WINDOW = DM_DEPTH // 2
#: The recorder's report period [s]: at 1 kHz, 50 messages per report, far below the window.
REPORT_PERIOD_S = 0.05


@dataclass
class FlowRun:
    """One flow-controlled stream: rate, latency, flow control and every count."""

    condition: str
    load_before: float
    load_after: float
    target_hz: float
    window: int
    rate_hz: float = 0.0
    p50_ms: float = 0.0
    p99_ms: float = 0.0
    held_back: dict[str, int] = field(default_factory=dict)
    held_back_s: float = 0.0
    #: CPU time [ms] per set point during the stream: node, recorder, this client
    cpu_ms: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def lossless(self) -> bool:
        """Whether published == received == recorded for set points and commands."""
        c = self.counts
        sent = c.get("setpoints_sent", -1)
        published = c.get("commands_published", -2)
        return (sent == c.get("setpoints_in_bag") == published == c.get("commands_received")
                == c.get("commands_in_bag") and c.get("recorder_lost") == 0)


class _Proc:
    """A node process logging to a file, stopped by its own PID only."""

    def __init__(self, command: Sequence[str], log: Path) -> None:
        self.log = log
        self._out = log.open("wb")
        self.popen = subprocess.Popen(list(command), stdout=self._out,
                                      stderr=subprocess.STDOUT, start_new_session=True)

    def output(self) -> str:
        """Everything the process printed so far."""
        if not self._out.closed:
            self._out.flush()
        return self.log.read_text(errors="replace")

    def stop(self) -> int:
        if self.popen.poll() is None:
            os.kill(self.popen.pid, signal.SIGINT)
            try:
                self.popen.wait(STOP_S)
            except subprocess.TimeoutExpired:
                os.kill(self.popen.pid, signal.SIGKILL)
                self.popen.wait(STOP_S)
        self._out.close()
        return self.popen.returncode


class FlowClient:
    """Set-point source with a credit window, and the command counter it paces on."""

    def __init__(self, shape: tuple[int, int]) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from std_msgs.msg import Float64MultiArray

        from es_msgs_py.arrays import grid_to_msg
        from es_msgs_py.topics import COMMAND, DIAGNOSTICS, SETPOINT, TEMPERATURE, qos_for

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("bench_flow_client", context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.setpoints = self.node.create_publisher(Float64MultiArray, SETPOINT,
                                                    qos_for(SETPOINT))
        self.temperature = self.node.create_publisher(Float64MultiArray, TEMPERATURE,
                                                      qos_for(TEMPERATURE))
        self.commands = self.node.create_subscription(Float64MultiArray, COMMAND,
                                                      self._on_command, qos_for(COMMAND))
        # the recorder's counts, its acknowledgement (``--report-period`` REPORT_PERIOD_S)
        self.recorded: dict[str, int] = {}
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics,
                                      qos_for(DIAGNOSTICS))
        self.sent = 0
        self.received = 0
        self.received_at: list[float] = []
        self.last_command: Any = None
        phases = np.random.default_rng(0).uniform(0, 2 * np.pi, shape)
        self.messages = [grid_to_msg(40e-9 + 25e-9 * np.sin(phases + k * 0.4))
                         for k in range(16)]
        self.estimate = grid_to_msg(np.full(shape, 46.0))

    def _on_command(self, msg: Any) -> None:
        self.received += 1
        self.last_command = msg
        self.received_at.append(time.perf_counter())

    def wait(self, done: Any, what: str, timeout: float, procs: Sequence[_Proc],
             required: bool = True) -> bool:
        """Spin until ``done()``; after ``timeout`` s raise naming ``what``, or return False.

        Raises:
            RuntimeError: one of ``procs`` exited, or (``required``) the timeout passed.

        """
        deadline = time.monotonic() + timeout
        while not done():
            dead = [p for p in procs if p.popen.poll() is not None]
            if dead:
                raise RuntimeError(f"{dead[0].log.stem} exited: {dead[0].output()[-800:]}")
            if time.monotonic() > deadline:
                if not required:
                    return False
                raise RuntimeError(f"{what}: not within {timeout:g} s")
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def _on_diagnostics(self, msg: Any) -> None:
        from es_msgs_py.topics import COMMAND, SETPOINT

        for status in msg.status:
            if status.name != "record: bag":
                continue
            for pair in status.values:
                for topic in (SETPOINT, COMMAND):
                    if pair.key == f"{topic} received" and pair.value.isdigit():
                        self.recorded[topic] = int(pair.value)

    def behind(self, window: int) -> str | None:
        """Why the next set point must wait, or None: the node's or the recorder's window."""
        from es_msgs_py.topics import COMMAND, SETPOINT

        if self.sent - self.received >= window:  # one command per set point, in order
            return "node"
        if (self.sent - self.recorded.get(SETPOINT, 0) >= RECORDER_WINDOW
                or self.received - self.recorded.get(COMMAND, 0) >= RECORDER_WINDOW):
            return "recorder"
        return None

    def stream(self, rate_hz: float, seconds: float, window: int
               ) -> tuple[np.ndarray, dict[str, int], float]:
        """Send ``rate_hz * seconds`` set points; each waits while :meth:`behind` says so.

        Returns:
            (send times [s, perf_counter], set points held back per reason, total time held
            back [s]).

        """
        count = round(rate_hz * seconds)
        period = 1.0 / rate_hz
        sent_at = np.empty(count)
        held = {"node": 0, "recorder": 0}
        held_s = 0.0
        due = time.perf_counter()
        for k in range(count):
            while (left := due - time.perf_counter()) > 0.0:
                self.executor.spin_once(timeout_sec=left)
            reason = self.behind(window)
            if reason is not None:
                held[reason] += 1
                start = time.perf_counter()
                while self.behind(window) is not None:
                    self.executor.spin_once(timeout_sec=1.0)
                held_s += time.perf_counter() - start
                due = time.perf_counter()  # the schedule restarts from the acknowledgement
            sent_at[k] = time.perf_counter()
            self.setpoints.publish(self.messages[k % len(self.messages)])
            self.sent += 1
            due += period
        return sent_at, held, held_s

    def close(self) -> None:
        """Destroy the client's node and shut its context down."""
        import rclpy

        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (``/proc/<pid>/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _load() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


def flow_run(condition: str, shape: tuple[int, int], *, rate_hz: float, seconds: float,
             window: int, log_dir: Path, profile: bool = False) -> FlowRun:
    """One stream with the recorder beside the node; ``condition`` 'idle' or 'two CPU hogs'.

    Raises:
        RuntimeError: a process died, or readiness or the last commands never came.

    """
    from common.load import hogs

    from es_bringup.bringup import executable
    from es_bringup.invariants import published_counts_from_log, recorder_counts_from_log
    from es_msgs_py.bag import read_bag
    from es_msgs_py.topics import COMMAND, SETPOINT

    rows, cols = shape
    run = FlowRun(condition, _load(), 0.0, rate_hz, window)
    tag = condition.replace(" ", "_")
    with tempfile.TemporaryDirectory(prefix="bench_flow_") as tmp, \
            hogs(cpu=2 if condition != "idle" else 0):
        bag = Path(tmp) / "bag"
        recorder = _Proc([str(executable("es_recordings", "record")), "-o", str(bag),
                          "--report-period", str(REPORT_PERIOD_S), SETPOINT, COMMAND],
                         log_dir / f"flow_record_{tag}.log")
        start = (
            [sys.executable, "-m", "cProfile", "-o", str(log_dir / f"flow_feedforward_{tag}.prof"),
             "-m", "es_feedforward.feedforward_node"]
            if profile
            else [str(executable("es_feedforward", "feedforward_node"))]
        )
        node = _Proc([*start, "--ros-args", "-p", f"rows:={rows}", "-p", f"cols:={cols}",
                      "-p", "temperature_timeout:=0.0", "-p", "ready_subscribers:=2"],
                     log_dir / f"flow_feedforward_{tag}.log")
        client = FlowClient(shape)
        procs = [recorder, node]
        try:
            client.wait(lambda: client.setpoints.get_subscription_count() >= 2
                        and client.temperature.get_subscription_count() >= 1
                        and client.commands.get_publisher_count() >= 1
                        and "ready: every input matched" in node.output(),
                        "node and recorder matched", READY_S, procs)
            client.temperature.publish(client.estimate)
            # set points one at a time until a command is not 0 V: the estimate was taken
            while client.last_command is None or not np.any(client.last_command.data):
                client.setpoints.publish(client.messages[0])
                client.sent += 1
                client.wait(lambda: client.received >= client.sent, "a command", READY_S, procs)
            base = client.received
            cpu_before = [_cpu_s(node.popen.pid), _cpu_s(recorder.popen.pid), time.process_time()]
            sent_at, run.held_back, run.held_back_s = client.stream(rate_hz, seconds, window)
            cpu_after = [_cpu_s(node.popen.pid), _cpu_s(recorder.popen.pid), time.process_time()]
            run.cpu_ms = {name: (after - before) * 1e3 / len(sent_at) for name, before, after
                          in zip(("node", "recorder", "client"), cpu_before, cpu_after,
                                 strict=True)}
            client.wait(lambda: client.received >= client.sent, "every command back",
                        DRAIN_S, procs)
            # the recorder drained too, before it is stopped (in flight at SIGINT: not recorded)
            # (what it never reports is a loss: the counts below show it)
            client.wait(lambda: client.recorded.get(SETPOINT) == client.sent
                        and client.recorded.get(COMMAND) == client.received,
                        "the recorder's report of every set point and command", DRAIN_S, procs,
                        required=False)
            back = np.asarray(client.received_at[base:base + len(sent_at)])
            latency = back - sent_at
            run.rate_hz = (len(sent_at) - 1) / float(sent_at[-1] - sent_at[0])
            run.p50_ms = float(np.percentile(latency, 50)) * 1e3
            run.p99_ms = float(np.percentile(latency, 99)) * 1e3
        finally:
            node.stop()
            recorder.stop()
            client.close()
        run.load_after = _load()
        published = published_counts_from_log(node.output().splitlines(), (COMMAND,))
        recorded = recorder_counts_from_log(recorder.output().splitlines())
        in_bag = read_bag(bag, [SETPOINT, COMMAND])
        run.counts = {
            "setpoints_sent": client.sent,
            "setpoints_in_bag": len(in_bag[SETPOINT]) if SETPOINT in in_bag else 0,
            "commands_published": published.get(COMMAND, -1),
            "commands_received": client.received,
            "commands_in_bag": len(in_bag[COMMAND]) if COMMAND in in_bag else 0,
            "recorder_lost": sum(c.lost for c in recorded.values()),
        }
    return run


def flow_runs(shape: tuple[int, int] = (64, 64), *, rate_hz: float = 1000.0,
              seconds: float = 10.0, window: int = DEFAULT_WINDOW,
              log_dir: Path | None = None, profile: bool = False) -> list[FlowRun]:
    """Run the stream idle, then beside two CPU hogs; return both runs.

    With ``profile`` the node runs under cProfile (``flow_feedforward_<condition>.prof`` in
    ``log_dir``): where its time goes, at the cost of its speed.
    """
    logs = log_dir or Path(tempfile.mkdtemp(prefix="bench_flow_logs_"))
    logs.mkdir(parents=True, exist_ok=True)
    return [flow_run(c, shape, rate_hz=rate_hz, seconds=seconds, window=window, log_dir=logs,
                     profile=profile) for c in ("idle", "two CPU hogs")]


def section_flow(settings: Any, results: Any, log_dir: Path) -> None:
    """``./scripts/bench --only flow``: the runs, in turns per repeat, as bench records."""
    from common.benchlib import Record

    seconds = 10.0 if settings.repeats > 1 else 3.0
    runs: dict[str, list[FlowRun]] = {}
    for _ in range(settings.repeats):
        for run in flow_runs(rate_hz=1000.0, seconds=seconds, log_dir=log_dir):
            runs.setdefault(run.condition, []).append(run)
    n = 64 * 64
    for condition, done in runs.items():
        tag = "idle" if condition == "idle" else "hogs"
        for name, values, unit in (
            ("rate", [r.rate_hz for r in done], "Hz"),
            ("latency_p50", [r.p50_ms for r in done], "ms"),
            ("latency_p99", [r.p99_ms for r in done], "ms"),
            ("held_back", [sum(r.held_back.values()) for r in done], "set points"),
            ("node_cpu", [r.cpu_ms["node"] for r in done], "ms per set point"),
            ("lost", [0 if r.lossless else 1 for r in done], "runs with a loss"),
        ):
            results.records.append(Record.of(f"flow_{tag}_{name}", n, values, unit))
        for i, r in enumerate(done):
            counts = ", ".join(f"{k} {v}" for k, v in r.counts.items())
            results.notes.append(
                f"flow {condition} run {i + 1}: load average {r.load_before:.1f} -> "
                f"{r.load_after:.1f}; {counts}; held back {r.held_back} "
                f"({r.held_back_s:.2f} s); CPU ms per set point "
                + ", ".join(f"{k} {v:.2f}" for k, v in r.cpu_ms.items()))
            if not r.lossless:
                results.failures.append(f"flow {condition} run {i + 1} lost messages: {counts}")
    results.notes.append(
        f"flow_*: set points at 1 kHz for {seconds:g} s to the feedforward node at 64 x 64 with "
        f"a recorder on /dm/setpoint and /dm/command, at most {DEFAULT_WINDOW} without their "
        "command (flow control, docs/architecture.md QoS); idle, then beside two CPU hogs "
        "(bench/common/load.py). rate: set points per second the stream achieved; latency: set "
        "point published -> its command received; held_back: set points that waited for the "
        "window; node_cpu: the node process's CPU time per set point during the stream (the "
        "rest of its wall time per set point is waiting for a core); lost: runs where "
        "published == received == recorded did not hold.")


def main(argv: Sequence[str] | None = None) -> int:
    """Print the runs as JSON; exit 1 when a run lost anything."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--window", type=int, default=DEFAULT_WINDOW)
    parser.add_argument("--shape", type=int, nargs=2, default=(64, 64))
    parser.add_argument("--log-dir", type=Path, default=None)
    parser.add_argument("--profile", action="store_true", help="node under cProfile")
    ns = parser.parse_args(argv)
    runs = flow_runs(tuple(ns.shape), rate_hz=ns.rate, seconds=ns.seconds, window=ns.window,
                     log_dir=ns.log_dir, profile=ns.profile)
    print(json.dumps([{**asdict(r), "lossless": r.lossless} for r in runs], indent=1))
    return 0 if all(r.lossless for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
