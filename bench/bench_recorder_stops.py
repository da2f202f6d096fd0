"""Ctrl-C storm on the recorder: crashes per N SIGINT stops while messages are in flight.

Usage (from the repository root, after ./scripts/bootstrap)::

    .venv/bin/python bench/bench_recorder_stops.py [--stops 50] [--cpu-hogs 2]

Each stop starts ``record`` (installed launcher, the tests' pattern) on /dm/command,
/dm/temperature_raw and /diagnostics, waits until it says ready on /diagnostics (its
subscriptions have matched this process's publishers), publishes at about 1 kHz for a
random 0.1-1 s and sends SIGINT to the recorder by PID while still publishing (what Ctrl-C
does during a run). A stop is a crash when the recorder exits otherwise than 0 (SIGSEGV:
-11), a native stack was printed (faulthandler), it took longer than :data:`STOP_LIMIT_S`,
or the bag has no metadata.yaml.
``--cpu-hogs`` CPU hogs (``bench/common/load.py``) run beside the storm. :func:`recorder_stops`
returns the counts and stop times; ``main`` prints them as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import rclpy
from common.load import hogs
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import Executor, SingleThreadedExecutor
from std_msgs.msg import Float64MultiArray

from es_msgs_py import topics
from es_msgs_py.arrays import grid_to_msg
from es_msgs_py.diagnostics import ready_nodes
from es_recordings.record import NODE_NAME

ROOT = Path(__file__).resolve().parents[1]

RECORD = ROOT / ".venv" / "lib" / "es_recordings" / "record"
#: Longest wait [s] for the recorder's subscriptions to match, and for a stop to finish.
START_LIMIT_S = 60.0
STOP_LIMIT_S = 30.0
#: What a native crash leaves in the output.
CRASH_MARKS = ("Fatal Python error", "Segmentation", "Aborted")
RECORDED = (topics.COMMAND, topics.TEMPERATURE_RAW, topics.DIAGNOSTICS)


@dataclass
class StormResult:
    """The outcome of a Ctrl-C storm on the recorder."""

    stops: int = 0
    crashes: int = 0
    cpu_hogs: int = 0
    load_average: list[float] = field(default_factory=list)
    stop_seconds: list[float] = field(default_factory=list)
    crash_notes: list[str] = field(default_factory=list)


def _wait_ready(
    executor: Executor, ready: list[float], started: float, proc: subprocess.Popen[bytes]
) -> None:
    """Spin ``node`` until the recorder started at ``started`` (wall clock, s) says ready.

    Its own report on /diagnostics, stamped after its start (a previous recorder's report
    may still be queued), not a publisher's subscription count: a recorder that crashed
    before still counts as a matched subscription until its DDS lease runs out.
    """
    deadline = time.monotonic() + START_LIMIT_S
    while not any(stamp >= started for stamp in ready):
        if proc.poll() is not None:
            raise RuntimeError(f"the recorder exited with {proc.returncode} before it was ready")
        if time.monotonic() > deadline:
            raise RuntimeError(f"the recorder never said ready within {START_LIMIT_S} s")
        executor.spin_once(timeout_sec=0.05)


def one_stop(
    executor: Executor, publishers: list, ready: list[float], bag: Path, rng: random.Random
) -> tuple[float, str]:
    """Run the recorder once, stop it with SIGINT while publishing; return (stop s, crash note)."""
    with tempfile.TemporaryFile() as log:
        started = time.time()
        proc = subprocess.Popen(
            [str(RECORD), "-o", str(bag), *RECORDED], stdout=log, stderr=subprocess.STDOUT
        )
        try:
            _wait_ready(executor, ready, started, proc)
            msg = grid_to_msg(np.zeros((12, 12)))
            end = time.monotonic() + rng.uniform(0.1, 1.0)
            while time.monotonic() < end:
                for pub in publishers:
                    pub.publish(msg)
                time.sleep(0.001)
            os.kill(proc.pid, signal.SIGINT)
            start = time.monotonic()
            for _ in range(20):  # messages still in flight while the recorder stops
                for pub in publishers:
                    pub.publish(msg)
                time.sleep(0.001)
            try:
                code = proc.wait(STOP_LIMIT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                return STOP_LIMIT_S, "took longer than the stop limit"
            took = time.monotonic() - start
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        log.seek(0)
        out = log.read().decode(errors="replace")
    marks = [m for m in CRASH_MARKS if m in out]
    if code != 0 or marks:
        native = out.find("Fatal Python error")
        return took, f"exit {code}: {out[native:native + 1500] if native >= 0 else out[-600:]}"
    if not (bag / "metadata.yaml").is_file():
        return took, "no metadata.yaml"
    return took, ""


def recorder_stops(stops: int, cpu_hogs: int = 0, seed: int = 0) -> StormResult:
    """Run ``stops`` recorder start/publish/SIGINT cycles beside ``cpu_hogs`` CPU hogs."""
    result = StormResult(cpu_hogs=cpu_hogs)
    rng = random.Random(seed)
    context = rclpy.Context()  # its own: the benchmark may have initialised rclpy already
    rclpy.init(context=context)
    node = rclpy.create_node("recorder_storm", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    publishers = [
        node.create_publisher(Float64MultiArray, t, topics.qos_for(t)) for t in RECORDED[:2]
    ]
    ready: list[float] = []  # wall-clock stamps [s] of "record: ready" reports

    def on_diagnostics(msg: DiagnosticArray) -> None:
        if ready_nodes(msg).get(NODE_NAME):
            ready.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)

    node.create_subscription(
        DiagnosticArray, topics.DIAGNOSTICS, on_diagnostics, topics.qos_for(topics.DIAGNOSTICS)
    )
    load = hogs(cpu=cpu_hogs, memio=0, seconds=3600.0) if cpu_hogs else nullcontext()
    try:
        with load, tempfile.TemporaryDirectory() as scratch:
            for k in range(stops):
                took, note = one_stop(executor, publishers, ready, Path(scratch) / f"bag{k}", rng)
                result.stops += 1
                result.stop_seconds.append(round(took, 3))
                if note:
                    result.crashes += 1
                    result.crash_notes.append(f"stop {k}: {note}")
                    print(f"stop {k}: CRASH {note}", file=sys.stderr, flush=True)
            result.load_average = [round(x, 1) for x in os.getloadavg()]
    finally:
        executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
    return result


def main() -> int:
    """Run the storm and print its result as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stops", type=int, default=50)
    parser.add_argument("--cpu-hogs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    ns = parser.parse_args()
    result = recorder_stops(ns.stops, ns.cpu_hogs, ns.seed)
    print(json.dumps(asdict(result), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
