"""Benchmarks of es_msgs_py: array <-> message conversion, bag reading, recorder throughput.

Run all three (about a minute):

    .venv/bin/python bench/bench_convert.py

or call the functions from another benchmark script. Figures are medians of repeats on the
machine at hand; nothing here is asserted.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class ConversionTiming:
    """Median times in microseconds for one array size."""

    size: int
    to_msg_us: float
    from_msg_us: float
    memcpy_us: float

    @property
    def overhead_us(self) -> float:
        """Round trip minus two plain copies: the Python work the conversion adds."""
        return self.to_msg_us + self.from_msg_us - 2 * self.memcpy_us


def _median_us(func: object, repeats: int, number: int) -> float:
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(number):
            func()  # type: ignore[operator]
        runs.append((time.perf_counter() - start) / number)
    return float(np.median(runs) * 1e6)


def bench_conversion(
    sizes: tuple[int, ...] = (144, 1024, 4096, 16384), repeats: int = 15, number: int = 2000
) -> list[ConversionTiming]:
    """Time grid_to_msg and msg_to_grid for square-ish grids of ``sizes`` elements."""
    from es_msgs_py.arrays import grid_to_msg, msg_to_grid

    results = []
    for size in sizes:
        side = int(np.sqrt(size))
        grid = np.random.default_rng(0).normal(size=(side, size // side))
        msg = grid_to_msg(grid)
        out = np.empty_like(grid)
        results.append(
            ConversionTiming(
                size,
                _median_us(lambda g=grid: grid_to_msg(g), repeats, number),
                _median_us(lambda m=msg, s=grid.shape: msg_to_grid(m, s), repeats, number),
                _median_us(lambda g=grid, o=out: np.copyto(o, g), repeats, number),
            )
        )
    return results


@dataclass(frozen=True)
class RecorderThroughput:
    """Outcome of one recorder run."""

    published: int
    written: int
    publish_seconds: float
    size: int

    @property
    def rate_hz(self) -> float:
        """Messages per second the publisher achieved (the recorder kept up if none lost)."""
        return self.published / self.publish_seconds


def bench_recorder(
    rate_hz: float = 1000.0, seconds: float = 10.0, size: int = 4096, storage: str = "mcap"
) -> RecorderThroughput:
    """Publish ``size``-element grids at ``rate_hz`` for ``seconds`` into a recorder process.

    Uses the installed ``lib/es_recordings/record`` launcher and the ROS_DOMAIN_ID of the
    environment; returns how many messages reached the bag.
    """
    import rclpy
    from rclpy.qos import QoSProfile

    from es_msgs_py.arrays import grid_to_msg
    from es_msgs_py.bag import read_bag
    from es_msgs_py.topics import COMMAND, DM_QOS

    side = int(np.sqrt(size))
    count = int(rate_hz * seconds)
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bag"
        launcher = Path(sys.prefix) / "lib" / "es_recordings" / "record"
        recorder = subprocess.Popen(
            [str(launcher), "-o", str(bag), "--storage", storage, COMMAND],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        context = rclpy.Context()
        rclpy.init(context=context)
        node = rclpy.create_node("bench_publisher", context=context)
        try:
            qos = QoSProfile(
                history=DM_QOS.history,
                depth=count,
                reliability=DM_QOS.reliability,
                durability=DM_QOS.durability,
            )
            publisher = node.create_publisher(type(grid_to_msg(np.zeros((1, 1)))), COMMAND, qos)
            deadline = time.monotonic() + 30.0
            while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(0.5)
            grid = np.zeros((side, size // side))
            start = time.perf_counter()
            for i in range(count):
                grid[0, 0] = i
                publisher.publish(grid_to_msg(grid))
                while time.perf_counter() < start + (i + 1) / rate_hz:
                    pass
            elapsed = time.perf_counter() - start
            time.sleep(2.0)  # let the recorder drain its queue
        finally:
            node.destroy_node()
            rclpy.shutdown(context=context)
            os.kill(recorder.pid, signal.SIGINT)
            recorder.wait(30)
        written = len(read_bag(bag)[COMMAND])
    return RecorderThroughput(count, written, elapsed, size)


def bench_read(messages: int = 150_000, shape: tuple[int, int] = (32, 32)) -> tuple[float, int]:
    """Write then read one grid topic of ``messages`` messages; return (read seconds, bytes)."""
    from es_msgs_py.bag import read_bag, write_array_bag

    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bag"
        values = np.zeros((messages, *shape))
        values[:, 0, 0] = np.arange(messages)
        write_array_bag(bag, {"/dm/command": (np.arange(messages) / 500.0, values)})
        del values
        size = sum(p.stat().st_size for p in bag.iterdir())
        start = time.perf_counter()
        read_bag(bag)
        return time.perf_counter() - start, size


def main() -> None:
    """Print every benchmark's figures."""
    print("numpy -> Float64MultiArray -> numpy (median us)")
    print(f"{'N':>6} {'to_msg':>8} {'from_msg':>9} {'memcpy':>7} {'overhead':>9}")
    for t in bench_conversion():
        print(
            f"{t.size:>6} {t.to_msg_us:>8.2f} {t.from_msg_us:>9.2f} {t.memcpy_us:>7.2f} "
            f"{t.overhead_us:>9.2f}"
        )
    seconds, size = bench_read()
    print(f"read_bag: 150000 x 32x32 grids ({size / 1e9:.2f} GB) in {seconds:.2f} s")
    for storage in ("mcap", "sqlite3"):
        run = bench_recorder(storage=storage)
        print(
            f"recorder ({storage}): published {run.published} x {run.size} doubles at "
            f"{run.rate_hz:.0f} Hz, written {run.written}"
        )


if __name__ == "__main__":
    main()
