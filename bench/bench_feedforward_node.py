r"""Benchmark of the feedforward node process: set-point-to-command latency and message rate.

Usage (from the repository root, after ./scripts/bootstrap)::

    ROS_DOMAIN_ID=211 ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST \\
        .venv/bin/python bench/bench_feedforward_node.py [--rows 64 --cols 64]

Starts the installed ``feedforward_node`` (inverse_hyperbolic, thesis laws) and, for the
comparison, a plain rclpy relay process (``--relay``: republishes every /dm/setpoint message
on /dm/command unchanged) and measures, one after the other:

- latency: set points paced at ``--rate`` Hz for ``--seconds``; time from publish to the
  command's arrival in this process (p50, p99, max) and the share of set points answered;
- throughput: set points sent as fast as the answers come back (at most ``--window`` in
  flight), messages per second; the node's rate is reported as a ratio to the relay's.

Each command is matched to its set point by a sequence number carried in actuator 0's set
point (1 pm steps; recovered from the voltage through the forward model).
:func:`bench_node` returns the figures for a benchmark suite; ``main`` prints them.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

STEP_M = 1e-12  # sequence number unit carried in actuator 0's set point
BASE_M = 50e-9
TEMPERATURE_C = 46.0


@dataclass(frozen=True)
class NodeFigures:
    """Latency and throughput of one process (feedforward node or relay)."""

    name: str
    p50_ms: float
    p99_ms: float
    max_ms: float
    answered: float
    rate_hz: float


def _relay_main() -> int:
    """Plain rclpy relay: /dm/setpoint -> /dm/command, message unchanged."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from std_msgs.msg import Float64MultiArray

    from es_msgs_py.topics import COMMAND, SETPOINT, qos_for

    rclpy.init()
    node = rclpy.create_node("relay")
    pub = node.create_publisher(Float64MultiArray, COMMAND, qos_for(COMMAND))
    node.create_subscription(Float64MultiArray, SETPOINT, pub.publish, qos_for(SETPOINT))
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _measure(
    name: str, decode: object, shape: tuple[int, int], args: argparse.Namespace
) -> NodeFigures:
    import rclpy
    from std_msgs.msg import Float64MultiArray

    from es_msgs_py.arrays import grid_to_msg
    from es_msgs_py.topics import COMMAND, SETPOINT, TEMPERATURE, qos_for

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("bench_ff", context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    sent: dict[int, float] = {}
    latencies: list[float] = []
    received = [0]

    def on_command(msg: Float64MultiArray) -> None:
        now = time.perf_counter()
        seq = decode(msg.data[0])  # type: ignore[operator]
        start = sent.pop(seq, None)
        if start is not None:
            latencies.append(now - start)
        received[0] += 1

    node.create_subscription(Float64MultiArray, COMMAND, on_command, qos_for(COMMAND))
    setpoint = node.create_publisher(Float64MultiArray, SETPOINT, qos_for(SETPOINT))
    temperature = node.create_publisher(Float64MultiArray, TEMPERATURE, qos_for(TEMPERATURE))
    deadline = time.monotonic() + 20.0
    while setpoint.get_subscription_count() == 0 or node.count_publishers(COMMAND) == 0:
        executor.spin_once(timeout_sec=0.05)
        if time.monotonic() > deadline:
            raise RuntimeError(f"{name}: no connection")
    temperature.publish(grid_to_msg(np.full(shape, TEMPERATURE_C)))
    grid = np.full(shape, BASE_M)
    messages = []
    for seq in range(1, 65536):
        grid[0, 0] = BASE_M + seq * STEP_M
        messages.append(grid_to_msg(grid))
        if len(messages) >= int(args.rate * args.seconds) + 20000:
            break

    def drain(seconds: float) -> None:
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            executor.spin_once(timeout_sec=0.001)

    drain(0.5)
    # warm-up, then paced latency run
    seq = 0
    period = 1.0 / args.rate
    count = int(args.rate * args.seconds)
    next_time = time.perf_counter()
    for _ in range(count + 200):
        seq += 1
        while True:
            now = time.perf_counter()
            if now >= next_time:
                break
            executor.spin_once(timeout_sec=max(0.0, next_time - now))
        if seq == 200:
            latencies.clear()
        sent[seq] = time.perf_counter()
        setpoint.publish(messages[seq - 1])
        next_time += period
        executor.spin_once(timeout_sec=0.0)
    drain(0.5)
    lat = np.array(latencies[-count:]) * 1e3
    answered = len(lat) / count
    # throughput: keep at most `window` set points in flight
    sent.clear()
    received[0] = 0
    start_seq = seq
    start = time.perf_counter()
    total = min(len(messages) - start_seq - 1, int(args.rate * args.seconds * 2))
    while seq - start_seq < total:
        if seq - start_seq - received[0] < args.window:
            seq += 1
            sent[seq] = time.perf_counter()
            setpoint.publish(messages[seq - 1])
            executor.spin_once(timeout_sec=0.0)
        else:
            executor.spin_once(timeout_sec=0.01)
    while received[0] < total and time.perf_counter() - start < 60.0:
        executor.spin_once(timeout_sec=0.01)
    rate = received[0] / (time.perf_counter() - start)
    executor.remove_node(node)
    node.destroy_node()
    rclpy.shutdown(context=context)
    return NodeFigures(
        name,
        float(np.percentile(lat, 50)) if lat.size else float("nan"),
        float(np.percentile(lat, 99)) if lat.size else float("nan"),
        float(lat.max()) if lat.size else float("nan"),
        answered,
        rate,
    )


def bench_node(args: argparse.Namespace) -> list[NodeFigures]:
    """Measure the feedforward node and the relay; return their figures."""
    from es_feedforward.models import hyperbolic_forward
    from es_feedforward.params import ActuatorParams

    shape = (args.rows, args.cols)
    params = ActuatorParams()
    prefix = Path(sys.prefix)

    def decode_voltage(v: float) -> int:
        return round((float(hyperbolic_forward(v, TEMPERATURE_C, params)) - BASE_M) / STEP_M)

    def decode_setpoint(z: float) -> int:
        return round((z - BASE_M) / STEP_M)

    out = []
    runs = [
        (
            "feedforward_node",
            [
                str(prefix / "lib/es_feedforward/feedforward_node"),
                "--ros-args",
                "-p",
                f"rows:={args.rows}",
                "-p",
                f"cols:={args.cols}",
                "-p",
                "temperature_timeout:=0.0",
            ],
            decode_voltage,
        ),
        ("relay", [sys.executable, __file__, "--relay"], decode_setpoint),
    ]
    for name, command, decode in runs:
        proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            time.sleep(1.0)
            out.append(_measure(name, decode, shape, args))
        finally:
            os.kill(proc.pid, signal.SIGINT)
            proc.wait(10)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print latency and throughput of the node and the relay."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--relay", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--rows", type=int, default=64)
    parser.add_argument("--cols", type=int, default=64)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--window", type=int, default=4)
    args = parser.parse_args(argv)
    if args.relay:
        return _relay_main()
    figures = bench_node(args)
    print(f"{args.rows} x {args.cols}, {args.rate:.0f} Hz for {args.seconds:.0f} s")
    header = ("p50 ms", "p99 ms", "max ms", "answered", "msg/s")
    print(f"{'process':18s} " + " ".join(f"{h:>8s}" for h in header))
    for f in figures:
        print(
            f"{f.name:18s} {f.p50_ms:8.3f} {f.p99_ms:8.3f} {f.max_ms:8.3f} "
            f"{f.answered:8.3f} {f.rate_hz:8.0f}"
        )
    if len(figures) == 2 and figures[1].rate_hz > 0:
        print(f"node / relay message rate: {figures[0].rate_hz / figures[1].rate_hz:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
