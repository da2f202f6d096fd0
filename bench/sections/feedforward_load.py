"""Section ``feedforward_load``: the feedforward node with a recorder, idle and loaded."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from common.benchlib import Context, Process, Record, Settings, launcher, processes
from common.dds_client import PACED_RATE, RATE_WINDOW, DdsClient

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


def _wait_diagnostics(client: DdsClient, process: Process, ready: Callable[[dict[str, str]], bool],
                   what: str, timeout: float = 60.0) -> None:
    """Spin until the /diagnostics values (recorder's counts, ``<node>: ready``) satisfy ``ready``.

    Readiness comes in as ``values["<node>: ready"] == "True"``.

    Raises:
        RuntimeError: they did not within ``timeout`` (names ``what`` and the last report).

    """
    from diagnostic_msgs.msg import DiagnosticArray

    from es_msgs_py.topics import DIAGNOSTICS, qos_for

    values: dict[str, str] = {}

    def on_report(msg: Any) -> None:
        from es_msgs_py.diagnostics import ready_nodes

        for status in msg.status:
            values.update((pair.key, pair.value) for pair in status.values)
        values.update((f"{name}: ready", str(ok)) for name, ok in ready_nodes(msg).items())

    sub = client.node.create_subscription(DiagnosticArray, DIAGNOSTICS, on_report,
                                          qos_for(DIAGNOSTICS))
    deadline = time.monotonic() + timeout
    try:
        while not ready(values):
            if time.monotonic() > deadline or not process.running():
                raise RuntimeError(f"{what}: not within {timeout:g} s (last report: "
                                   f"{ {k: v for k, v in values.items() if k.startswith('/')} })")
            client.executor.spin_once(timeout_sec=0.1)
    finally:
        client.node.destroy_subscription(sub)


def _count(values: dict[str, str], key: str) -> int:
    """Return the integer ``values[key]`` of a recorder report, -1 when absent or not a number."""
    value = values.get(key, "")
    return int(value) if value.isdigit() else -1


def _wait_recorder_matched(client: DdsClient, recorder: Process) -> None:
    """Wait until the recorder matched the set-point and command publishers (before any is sent).

    Raises:
        RuntimeError: it did not within the timeout.

    """
    from es_msgs_py.topics import COMMAND, SETPOINT

    keys = [f"{topic} publishers" for topic in (SETPOINT, COMMAND)]
    _wait_diagnostics(client, recorder, lambda v: all(_count(v, k) >= 1 for k in keys),
                   "publishers of " + " and ".join(keys))


def _wait_node_ready(client: DdsClient, node: Process) -> None:
    """Wait until the feedforward says it is ready (no command goes out before).

    With ``ready_subscribers:=2`` its command publisher has matched the client and the
    recorder then, so neither misses the first command.

    Raises:
        RuntimeError: it did not within the timeout.

    """
    from es_feedforward.feedforward_node import NODE_NAME

    key = f"{NODE_NAME}: ready"
    _wait_diagnostics(client, node, lambda v: v.get(key) == "True", key)


def _wait_recorder_has(client: DdsClient, recorder: Process) -> None:
    """Wait until the recorder's /diagnostics report every command the client received.

    Raises:
        RuntimeError: the recorder did not report them within the timeout.

    """
    from es_msgs_py.topics import COMMAND

    key = f"{COMMAND} received"
    _wait_diagnostics(client, recorder, lambda v: _count(v, key) >= client.received,
                   f"{client.received} commands received")


def _load_run(loaded: bool, settings: Settings, log_dir: Path, paced_s: float) -> LoadRun:
    """Feedforward at LOAD_SHAPE with a recorder on set points and commands, hogs or not."""
    from common.load import hogs

    from es_bringup.invariants import (
        RecorderCounts,
        published_counts_from_log,
        recorder_counts_from_log,
    )
    from es_msgs_py.bag import read_bag
    from es_msgs_py.topics import COMMAND, SETPOINT

    rows, cols = LOAD_SHAPE
    label = "loaded" if loaded else "idle"
    with tempfile.TemporaryDirectory(prefix="bench_load_") as tmp, \
            hogs(cpu=LOAD_CPU_HOGS if loaded else 0):
        bag = Path(tmp) / "bag"
        recorder = Process(f"record_{label}", [launcher("es_recordings", "record"), "-o", str(bag),
                                               SETPOINT, COMMAND], log_dir)
        node = Process(f"feedforward_{label}_{rows}x{cols}", [
            launcher("es_feedforward", "feedforward_node"), "--ros-args", "-p", f"rows:={rows}",
            "-p", f"cols:={cols}", "-p", "temperature_timeout:=0.0",
            "-p", "ready_subscribers:=2"], log_dir)  # the client and the recorder
        client = DdsClient(LOAD_SHAPE)
        try:
            with processes(node, recorder):  # the node stops first, the recorder last
                client.wait_for_peer(setpoint_readers=2, estimates=True)
                # matched before the first set point: what it misses later is a loss
                _wait_recorder_matched(client, recorder)
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
                "setpoints_recorded": recorded.get(SETPOINT, RecorderCounts(-1, -1)).written,
                "commands_recorded": recorded.get(COMMAND, RecorderCounts(-1, -1)).written,
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
        "(bench/common/load.py), in turns; latency_p99 one set point at a time, rate with "
        f"{RATE_WINDOW} in flight, paced_latency_p99 while set points stream at "
        f"{PACED_RATE:g} Hz for {paced_s:g} s; lost: set points without a command back plus "
        "set points and commands missing from the bag (published == received == recorded "
        "when 0); a paced p99 is left out of a run that lost commands (no pairing)."
    )
