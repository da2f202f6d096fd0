"""A node under test with timestamps: where the set-point-to-command time goes (bench only).

Runs the feedforward node (``feedforward``, its defaults) or the plain relay (``relay``,
bench/common/relay.py on the EventsExecutor) as ``run_node`` does, with the /dm/setpoint callback
wrapped: it records ``time.perf_counter()`` (CLOCK_MONOTONIC, one clock for every process of
the host) when the callback starts and when it returns (the command published). It also
records its timers' callbacks the same way and every garbage collection of the process
(start, end, generation; ``gc.callbacks``). At the stop it writes them to ``--out``
(``.npz``: ``callback`` (N, 2) [s], ``timer`` (T, 2), ``gc`` (M, 3)).
The wrapper costs two clock reads and an append per set point. ``PROBE_GC_FREEZE=0`` in the
environment skips run_node's collection and ``gc.freeze()`` before the spin (an A/B of it).

    (cd bench && ../.venv/bin/python -m common.probe_node {feedforward,relay} --out FILE ...)
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


class Stamps:
    """Callback and GC timestamps of one process [s, perf_counter]."""

    def __init__(self) -> None:
        self.callback: list[tuple[float, float]] = []
        self.timer: list[tuple[float, float]] = []
        self.gc: list[tuple[float, float, int]] = []
        self._gc_start = 0.0

    def on_gc(self, phase: str, info: dict[str, Any]) -> None:
        """``gc.callbacks`` hook: one (start, end, generation) row per collection."""
        now = time.perf_counter()
        if phase == "start":
            self._gc_start = now
        else:
            self.gc.append((self._gc_start, now, int(info["generation"])))

    def timed(self, callback: Callable[[Any], None]) -> Callable[[Any], None]:
        """Return ``callback`` recording (start, end) of every call."""
        clock, append = time.perf_counter, self.callback.append

        def wrapper(msg: Any) -> None:
            start = clock()
            callback(msg)
            append((start, clock()))

        return wrapper

    def timed_timer(self, callback: Callable[[], None]) -> Callable[[], None]:
        """Return a timer's ``callback`` recording (start, end) of every call."""
        clock, append = time.perf_counter, self.timer.append

        def wrapper() -> None:
            start = clock()
            callback()
            append((start, clock()))

        return wrapper

    def save(self, path: Path) -> None:
        """Write the stamps as ``.npz`` (``callback`` (N, 2), ``timer``, ``gc`` (M, 3))."""
        np.savez(path, callback=np.asarray(self.callback, float).reshape(-1, 2),
                 timer=np.asarray(self.timer, float).reshape(-1, 2),
                 gc=np.asarray(self.gc, float).reshape(-1, 3))


def make_probed(kind: str, out: Path) -> Callable[[], Any]:
    """Return a node factory for ``run_node``: the node of ``kind`` with its set points timed."""
    from es_msgs_py.topics import SETPOINT

    stamps = Stamps()
    gc.callbacks.append(stamps.on_gc)

    def make() -> Any:
        if kind == "relay":
            from common.relay import Relay

            node: Any = Relay()
        else:
            from es_feedforward.feedforward_node import FeedforwardNode

            node = FeedforwardNode()
        (sub,) = [s for s in node.subscriptions if s.topic_name == SETPOINT]
        sub.callback = stamps.timed(sub.callback)
        for timer in node.timers:
            timer.callback = stamps.timed_timer(timer.callback)
        close = getattr(node, "close", None)

        def close_and_save() -> None:
            if callable(close):
                close()
            stamps.save(out)

        node.close = close_and_save
        return node

    return make


def main() -> int:
    """Run the probed node until SIGINT/SIGTERM, then write its stamps."""
    from es_node_runtime import node_main

    if os.environ.get("PROBE_GC_FREEZE") == "0":  # the A of an A/B of run_node's freeze
        node_main.settle_garbage = lambda: None
    own = sys.argv[1:sys.argv.index("--ros-args")] if "--ros-args" in sys.argv else sys.argv[1:]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("kind", choices=("feedforward", "relay"))
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(own)
    return node_main.run_node(make_probed(args.kind, args.out), sys.argv)


if __name__ == "__main__":
    raise SystemExit(main())
