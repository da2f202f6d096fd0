"""Section ``feedforward_load``: the feedforward node with a recorder, idle and loaded."""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from benchlib import Context, Process, Record, Settings, launcher, processes
from dds_client import PACED_RATE, RATE_WINDOW, DdsClient

#: Grid and CPU hogs of the feedforward-under-load run (4096 doubles, two hogs: issue 17).
LOAD_SHAPE = (64, 64)
LOAD_CPU_HOGS = 2


@dataclass
class LoadRun:
    """One feedforward run with a recorder beside it, idle or beside CPU hogs."""

    p99_ms: float
    rate_hz: float
    paced_p99_ms: float | None
    paced_rate_hz: float
    counts: dict[str, int]

    @property
    def lost(self) -> int:
        """Set points without a command back, plus messages the recorder did not write."""
        c = self.counts
        return ((c["setpoints_sent"] - c["commands_received"])
                + (c["setpoints_sent"] - c["setpoints_in_bag"])
                + (c["commands_published"] - c["commands_in_bag"]))


def _wait_node_ready(client: DdsClient, node: Process, timeout: float = 60.0) -> None:
    """Wait until the node logs that it is ready (its inputs and outputs matched).

    Started with ``ready_subscribers:=2``, its command publisher has then matched the client
    and the recorder, so the recorder gets every command from the first on.

    Raises:
        RuntimeError: the node did not say so within ``timeout``, or it exited first.

    """
    deadline = time.monotonic() + timeout
    while "ready: every input matched" not in node.output():
        if not node.running():
            raise RuntimeError(f"{node.name} exited {node.popen.returncode} before it was "
                               f"ready:\n{node.output()}")
        if time.monotonic() > deadline:
            raise RuntimeError(f"{node.name} not ready within {timeout:g} s: its command "
                               "publisher did not match the client and the recorder")
        client.executor.spin_once(timeout_sec=0.1)


def _wait_recorder_has(client: DdsClient, recorder: Process, timeout: float = 60.0) -> None:
    """Wait until the recorder's /diagnostics report every command the client received.

    The node's command publisher matched the recorder before the first command went out
    (:func:`_wait_node_ready`): a command the recorder lacks here is lost, not start-up.

    Raises:
        RuntimeError: the recorder did not report them within ``timeout``.

    """
    from diagnostic_msgs.msg import DiagnosticArray

    from es_msgs_py.topics import COMMAND, DIAGNOSTICS, qos_for

    reported = -1

    def on_report(msg: Any) -> None:
        nonlocal reported
        for status in msg.status:
            for pair in status.values:
                if pair.key == f"{COMMAND} received" and pair.value.isdigit():
                    reported = int(pair.value)

    sub = client.node.create_subscription(DiagnosticArray, DIAGNOSTICS, on_report,
                                          qos_for(DIAGNOSTICS))
    deadline = time.monotonic() + timeout
    try:
        while reported < client.received:
            if time.monotonic() > deadline or not recorder.running():
                raise RuntimeError(f"recorder reports {reported} of {client.received} commands "
                                   f"after {timeout:g} s")
            client.executor.spin_once(timeout_sec=0.1)
    finally:
        client.node.destroy_subscription(sub)


def _load_run(loaded: bool, settings: Settings, log_dir: Path, paced_s: float) -> LoadRun:
    """Feedforward at LOAD_SHAPE with a recorder on set points and commands, hogs or not."""
    from load import hogs

    from es_bringup.invariants import published_counts_from_log, recorder_counts_from_log
    from es_msgs_py.bag import read_bag
    from es_msgs_py.topics import COMMAND, SETPOINT

    rows, cols = LOAD_SHAPE
    label = "loaded" if loaded else "idle"
    with tempfile.TemporaryDirectory(prefix="bench_load_") as tmp, \
            hogs(cpu=LOAD_CPU_HOGS if loaded else 0):
        bag = Path(tmp) / "bag"
        recorder = Process(f"record_{label}", [launcher("es_msgs_py", "record"), "-o", str(bag),
                                               SETPOINT, COMMAND], log_dir)
        node = Process(f"feedforward_{label}_{rows}x{cols}", [
            launcher("es_feedforward", "feedforward_node"), "--ros-args", "-p", f"rows:={rows}",
            "-p", f"cols:={cols}", "-p", "temperature_timeout:=0.0", "-p",
            "ready_subscribers:=2"], log_dir)
        client = DdsClient(LOAD_SHAPE)
        try:
            with processes(node, recorder):  # the node stops first, the recorder last
                client.wait_for_peer(setpoint_readers=2, estimates=True)
                _wait_node_ready(client, node)
                client.use_temperature()
                _wait_recorder_has(client, recorder)
                lat = client.latencies(settings.dds_latency_samples)
                rate, _ = client.rate(settings.dds_rate_seconds)
                paced, paced_rate, _ = client.paced(PACED_RATE, paced_s)
                client._wait_received(client.sent, 10.0)  # every late command, before the stop
                node.stop()
                recorder.stop()
            published = published_counts_from_log(node.output().splitlines(), (COMMAND,))
            recorded = recorder_counts_from_log(recorder.output().splitlines())
            in_bag = read_bag(bag, [SETPOINT, COMMAND])
            counts = {
                "setpoints_sent": client.sent,
                "commands_published": published.get(COMMAND, -1),
                "commands_received": client.received,
                "setpoints_recorded": recorded.get(SETPOINT, (-1, -1, -1))[1],
                "commands_recorded": recorded.get(COMMAND, (-1, -1, -1))[1],
                "setpoints_in_bag": len(in_bag[SETPOINT]) if SETPOINT in in_bag else 0,
                "commands_in_bag": len(in_bag[COMMAND]) if COMMAND in in_bag else 0,
            }
        finally:
            client.close()
    return LoadRun(float(np.percentile(lat, 99)) * 1e3, rate,
                   None if paced is None else float(np.percentile(paced, 99)) * 1e3,
                   paced_rate, counts)


def run(context: Context) -> None:
    """Feedforward at 4096 with a recorder, idle and beside two CPU hogs: rate, p99, loss."""
    settings, results, log_dir = context.settings, context.results, context.log_dir
    paced_s = 10.0 if settings.repeats > 1 else 3.0
    runs: dict[bool, list[LoadRun]] = {False: [], True: []}
    for _ in range(settings.repeats):
        for loaded in (False, True):  # in turns: a change of the machine's load hits both
            runs[loaded].append(_load_run(loaded, settings, log_dir, paced_s))
    n = LOAD_SHAPE[0] * LOAD_SHAPE[1]
    for loaded, label in ((False, "idle"), (True, "loaded")):
        done = runs[loaded]
        results.records.append(Record.of(f"load_{label}_rate", n, [r.rate_hz for r in done],
                                         "Hz"))
        results.records.append(Record.of(f"load_{label}_latency_p99", n,
                                         [r.p99_ms for r in done], "ms"))
        paced = [r.paced_p99_ms for r in done if r.paced_p99_ms is not None]
        if paced:
            results.records.append(Record.of(f"load_{label}_paced_latency_p99", n, paced, "ms"))
        results.records.append(Record.of(f"load_{label}_lost", n, [r.lost for r in done],
                                         "messages"))
        for i, r in enumerate(done):
            counts = ", ".join(f"{k} {v}" for k, v in r.counts.items())
            results.notes.append(f"load_{label} run {i + 1}: {counts}; client sent "
                                 f"{r.paced_rate_hz:.0f} Hz in the paced run")
    results.notes.append(
        f"load_*: the feedforward node at {LOAD_SHAPE[0]} x {LOAD_SHAPE[1]} with a recorder on "
        f"/dm/setpoint and /dm/command, idle and beside {LOAD_CPU_HOGS} CPU hogs "
        "(bench/load.py), in turns; latency_p99 one set point at a time, rate with "
        f"{RATE_WINDOW} in flight, paced_latency_p99 while set points stream at "
        f"{PACED_RATE:g} Hz for {paced_s:g} s; lost: set points without a command back plus "
        "set points and commands missing from the bag (published == received == recorded "
        "when 0); a paced p99 is left out of a run that lost commands (no pairing)."
    )
