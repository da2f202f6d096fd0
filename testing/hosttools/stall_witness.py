"""A witness of the machine's own stalls, run beside a latency measurement.

A real-time process that does nothing but sleep :data:`PERIOD` at a time and note every
wake-up that came more than :data:`LATE` late: on a shared or virtual machine even a process
that preempts every other one still waits tens of milliseconds at times (the host, other
tenants, the kernel). A set point that was slow while the witness was late was slow because
of the machine; one that was slow while the witness was on time was slow because of us
(the node, the client, DDS). Its CPU is a few per cent of one core.

    .venv/bin/python -m hosttools.stall_witness --out FILE [--cpu N]   (until SIGINT/SIGTERM)

``--cpu N`` pins it to CPU N: on a virtual machine the host can stall one virtual CPU and not
the other, so a benchmark runs one witness per CPU (:func:`witness_commands`) and merges
their files (:func:`load_all`).

It prints ``watching (real-time)`` or ``watching (normal priority)`` once its stop signals
are taken.

``FILE`` (``.npy``): one row per late wake-up, (due, woke) [s, ``time.perf_counter``, the
host's CLOCK_MONOTONIC, comparable with every process's stamps].
"""

from __future__ import annotations

import argparse
import signal
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Sleep of the witness per wake-up [s].
PERIOD = 1e-3
#: Lateness [s] from which a wake-up is noted.
LATE = 0.5e-3
#: SCHED_FIFO priority of the witness: above every process of the benchmark (and of anyone
#: else's normal processes), so that what delays it is the machine (the host, the kernel),
#: not the CPU use of the node it watches. Where real-time is not permitted, it runs at normal
#: priority (and then also sees the machine's load).
PRIORITY = 50
#: Most set points between two slow ones of one episode (MachineCheck).
EPISODE_GAP = 3


def real_time() -> bool:
    """Make this process real-time (SCHED_FIFO :data:`PRIORITY`); return whether it is."""
    import os

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PRIORITY))
    except OSError:  # not permitted: the witness then waits for the CPU like anyone
        return False
    return True


def watch(out: Path) -> None:
    """Sleep PERIOD at a time until SIGINT/SIGTERM; write the late wake-ups to ``out``."""
    stop: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _frame: stop.append(signum))
    print("watching", "(real-time)" if real_time() else "(normal priority)", flush=True)
    late: list[tuple[float, float]] = []
    clock = time.perf_counter
    due = clock() + PERIOD
    while not stop:
        time.sleep(max(due - clock(), 0.0))
        woke = clock()
        if woke - due > LATE:
            late.append((due, woke))
        due = max(due + PERIOD, woke)
    np.save(out, np.asarray(late, float).reshape(-1, 2))


def witness_commands(out_stem: Path) -> list[tuple[Path, list[str]]]:
    """Return (file, argv) of one witness per CPU this process may run on."""
    import os
    import sys

    return [(out_stem.with_name(f"{out_stem.name}_cpu{cpu}.npy"),
             [sys.executable, __file__, "--out",
              str(out_stem.with_name(f"{out_stem.name}_cpu{cpu}.npy")), "--cpu", str(cpu)])
            for cpu in sorted(os.sched_getaffinity(0))]


def load_all(paths: list[Path]) -> np.ndarray:
    """Return the late wake-ups of several witness files together, by time."""
    rows = np.concatenate([load(path) for path in paths]) if paths else np.empty((0, 2))
    return rows[np.argsort(rows[:, 0], kind="stable")]


def load(path: Path) -> np.ndarray:
    """Return a witness file's late wake-ups (due, woke) [s] ((0, 2) if it wrote none)."""
    return np.load(path) if path.exists() else np.empty((0, 2))


def during_stalls(stalls: np.ndarray, start: np.ndarray, end: np.ndarray,
                  min_stall: float) -> np.ndarray:
    """Return, per interval [start, end] [s], whether a witnessed stall overlapped it.

    Args:
        stalls: (due, woke) rows of :func:`load`.
        start: the intervals' starts, e.g. the set points' publish times (N,).
        end: their ends, e.g. the commands' reception times (N,).
        min_stall: only stalls at least this long [s] count.

    """
    long = stalls[stalls[:, 1] - stalls[:, 0] >= min_stall]
    if not len(long):
        return np.zeros(len(start), bool)
    order = np.argsort(long[:, 0])
    due, woke = long[order, 0], long[order, 1]
    latest_end = np.maximum.accumulate(woke)
    # the last stall that began before the interval ended must end after it began
    last = np.searchsorted(due, end, side="right") - 1
    return (last >= 0) & (latest_end[np.maximum(last, 0)] >= start)


@dataclass(frozen=True)
class MachineCheck:
    """A paced run's slow samples beside the machine's stalls the witness saw.

    Slow set points come in episodes (consecutive ones, at most :data:`EPISODE_GAP` apart):
    a stall and the backlog behind it. An episode is the machine's when a witnessed stall
    of at least half the target overlapped its first set point (from ``target`` before it
    was published to its command's reception); the rest are ours (node, client, DDS).

    Attributes:
        slow: set points whose command took longer than the target.
        slow_in_stall: of those, the ones in the machine's episodes.
        episodes: episodes of slow set points.
        stalls: witnessed stalls of at least half the target during the run.
        longest_ms: the longest witnessed stall during the run [ms] (0 if none).

    """

    slow: int
    slow_in_stall: int
    episodes: int
    stalls: int
    longest_ms: float

    @classmethod
    def of(cls, sent: np.ndarray, received: np.ndarray, witnessed: np.ndarray,
           target_s: float) -> MachineCheck:
        """Compare a run's (sent, received) stamps [s] with the witness's (due, woke) rows.

        A run that lost commands has no pairing of set points with commands (``received``
        empty): nothing to compare, all counts 0 and ``longest_ms`` NaN.
        """
        if not len(sent) or len(received) != len(sent):
            return cls(0, 0, 0, 0, float("nan"))
        inside = (witnessed[:, 1] >= sent[0] - target_s) & (witnessed[:, 0] <= received[-1])
        run_stalls = witnessed[inside]
        length = run_stalls[:, 1] - run_stalls[:, 0]
        slow = np.flatnonzero(received - sent > target_s)
        first = np.concatenate(([True], np.diff(slow) > EPISODE_GAP)) if len(slow) else slow
        starts = slow[first.astype(bool)]
        machine = during_stalls(run_stalls, sent[starts] - target_s, received[starts],
                                target_s / 2)
        episode = np.cumsum(first) - 1  # episode of each slow set point
        return cls(len(slow), int(machine[episode].sum()) if len(slow) else 0, len(starts),
                   int(np.count_nonzero(length >= target_s / 2)),
                   float(length.max() * 1e3) if len(length) else 0.0)


def main() -> int:
    """Watch until stopped."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--cpu", type=int, default=None, help="pin the witness to this CPU")
    args = parser.parse_args()
    if args.cpu is not None:
        import os

        os.sched_setaffinity(0, {args.cpu})
    watch(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
