"""Where a paced run's latency tail comes from: set point -> node -> command, leg by leg.

The scale case of bench_scale.py (paced set points, one command each) with the node under
test started as common.probe_node, which stamps its /dm/setpoint callback's start and end;
the client stamps its publishes and receptions and its own garbage collections. All stamps
are CLOCK_MONOTONIC (``time.perf_counter``) of one host, so each sample's latency splits into

- ``queued``: the node was still busy with the previous set point when this one was sent;
- ``in``: publish -> node callback start, the wait behind the previous callback excluded
  (DDS transport, the node's executor waking up and taking the sample);
- ``node``: the callback (conversion, compute, publish of the command);
- ``back``: callback end -> client callback (DDS back, the client's executor).

The feedforward node and the relay (same executor, no computation) take turns per repeat.
For the samples at or above each run's p99 it prints the mean of every leg, and every
stall (a run of consecutive slow samples) with the legs of its first sample and the
garbage collections of either process during it. ``--node-env KEY=VALUE`` sets an
environment variable of the node processes (an A/B of a setting, run in turns with
``--turns``).

    .venv/bin/python bench/bench_tail.py [--grid 128] [--rate 1000] [--seconds 3] [--repeats 2]
"""

from __future__ import annotations

import argparse
import gc
import os
import signal
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Set points at the start of a paced run whose latency is shown apart (one-off costs).
FIRST = 200
#: The legs of a sample's latency, in order (see the module docstring).
LEGS = ("queued", "in", "node", "back")


@dataclass(frozen=True)
class ProbedRun:
    """Stamps of one paced run [s, perf_counter]: per paced set point and per collection."""

    label: str
    sent: np.ndarray
    received: np.ndarray
    callback: np.ndarray
    node_gc: np.ndarray
    node_timer: np.ndarray
    client_gc: np.ndarray
    node_proc: dict[str, float]
    load: str
    machine: np.ndarray

    @property
    def latency(self) -> np.ndarray:
        """Set point published -> command received [s]."""
        return self.received - self.sent

    def legs(self) -> dict[str, np.ndarray]:
        """Return each leg [s] per sample (they add up to the latency)."""
        start, end = self.callback[:, 0], self.callback[:, 1]
        previous_end = np.concatenate(([-np.inf], end[:-1]))
        free = np.maximum(self.sent, previous_end)
        return {"queued": free - self.sent, "in": start - free, "node": end - start,
                "back": self.received - end}


def proc_counts(pid: int) -> dict[str, float]:
    """Return a process's CPU [s], page faults and context switches so far (/proc)."""
    import os

    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    status = dict(line.split(":", 1) for line in
                  Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    return {"cpu_s": (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK"),
            "minflt": int(fields[7]), "majflt": int(fields[9]),
            "voluntary_cs": int(status["voluntary_ctxt_switches"]),
            "involuntary_cs": int(status["nonvoluntary_ctxt_switches"])}


def node_command(kind: str, shape: tuple[int, int], out: Path, env: Sequence[str]) -> list[str]:
    """Return the argv of the probed ``feedforward`` (its defaults) or ``relay`` (events)."""
    rows, cols = shape
    ros = (["-r", "__node:=relay", "-p", "executor:=events"] if kind == "relay" else
           ["-p", f"rows:={rows}", "-p", f"cols:={cols}", "-p", "temperature_timeout:=0.0"])
    from common.benchlib import helper_command

    return ["env", *env, *helper_command("probe_node", kind, "--out", str(out), "--ros-args", *ros)]


def pause_later(pid: int, at_s: float, pause_s: float) -> threading.Thread:
    """Return a started thread that stops process ``pid`` at ``at_s`` for ``pause_s`` [s]."""

    def pause() -> None:
        time.sleep(at_s)
        os.kill(pid, signal.SIGSTOP)
        try:
            time.sleep(pause_s)
        finally:
            os.kill(pid, signal.SIGCONT)

    thread = threading.Thread(target=pause, daemon=True)
    thread.start()
    return thread


def probed_run(kind: str, label: str, shape: tuple[int, int], *, rate_hz: float,
               seconds: float, log_dir: Path, env: Sequence[str],
               pause_s: float = 0.0) -> ProbedRun:
    """Start the probed node, run one paced measurement, return its stamps.

    ``pause_s`` > 0: the node is stopped (SIGSTOP) for that long half-way through the run,
    like a scheduler stall of the machine, to see how long the stream takes to recover.

    Raises:
        RuntimeError: a command was lost (the pairing by order is then gone), or the node
            wrote no stamps.

    """
    from bench_scale import WARMUP, start_client
    from common.benchlib import Process, processes
    from hosttools.stall_witness import load_all, witness_commands

    out = log_dir / f"tail_{label}.npz"
    out.unlink(missing_ok=True)
    client_gc: list[tuple[float, float, int]] = []
    marks: list[float] = [0.0]

    def on_gc(phase: str, info: dict[str, int]) -> None:
        now = time.perf_counter()
        if phase == "start":
            marks[0] = now
        else:
            client_gc.append((marks[0], now, info["generation"]))

    witnesses = witness_commands(log_dir / f"tail_{label}_witness")
    for path, _ in witnesses:
        path.unlink(missing_ok=True)
    node = Process(f"tail_{label}", node_command(kind, shape, out, env), log_dir)
    watching = [Process(path.stem, argv, log_dir) for path, argv in witnesses]
    with processes(node, *watching):
        client = start_client(shape, 60.0, hold_check=kind == "feedforward")
        gc.callbacks.append(on_gc)
        try:
            first = len(client.received_at)
            before = proc_counts(node.popen.pid)
            pauser = (pause_later(node.popen.pid, seconds / 2, pause_s) if pause_s > 0
                      else None)
            latencies, _, lost = client.paced(rate_hz, seconds)
            if pauser is not None:
                pauser.join()
            after = proc_counts(node.popen.pid)
            received = np.asarray(client.received_at[first:])
        finally:
            gc.callbacks.remove(on_gc)
            client.close()
        for witness in watching:
            witness.stop()
    if latencies is None or lost:
        raise RuntimeError(f"{label}: {lost} command(s) lost")
    if not out.exists():
        raise RuntimeError(f"{label}: the node wrote no stamps (see {node.log_path})")
    stamps = np.load(out)
    callback = stamps["callback"][WARMUP:]
    if len(callback) != len(received):
        raise RuntimeError(f"{label}: {len(callback)} callbacks for {len(received)} commands")
    count = len(received)
    per_message = {key: (after[key] - before[key]) / count for key in before}
    return ProbedRun(label, client.paced_sent_at, received, callback, stamps["gc"],
                     stamps["timer"], np.asarray(client_gc, float).reshape(-1, 3), per_message,
                     " ".join(Path("/proc/loadavg").read_text().split()[:3]),
                     load_all([path for path, _ in witnesses]))


def overlapping(spans: np.ndarray, start: float, end: float, what: str) -> list[str]:
    """Return the ``spans`` (start, end[, generation]) overlapping [start, end], described."""
    hits = spans[(spans[:, 1] >= start) & (spans[:, 0] <= end)] if len(spans) else spans
    return [f"{what}{int(h[2]) if len(h) > 2 else ''} {(h[1] - h[0]) * 1e3:.2f} ms"
            for h in hits]


def gc_summary(gcs: np.ndarray, start: float, end: float) -> str:
    """Return count, longest and total [ms] of the collections within [start, end] by gen."""
    inside = gcs[(gcs[:, 0] >= start) & (gcs[:, 1] <= end)] if len(gcs) else gcs
    parts = []
    for gen in range(3):
        span = np.diff(inside[inside[:, 2] == gen][:, :2], axis=1).ravel() * 1e3
        if len(span):
            parts.append(f"gen{gen} {len(span)} (max {span.max():.2f}, total {span.sum():.2f} ms)")
    return ", ".join(parts) or "none"


def late_summary(late: np.ndarray) -> str:
    """Return how far [ms] a paced client's publishes fell behind their schedule."""
    return (f"p99 {np.percentile(late, 99) * 1e3:.2f}, max {late.max() * 1e3:.2f}, "
            f"over 1 ms: {np.count_nonzero(late > 1e-3)}")


def report(run: ProbedRun, rate_hz: float, stall_s: float = 1e-3,
           stall_gap: int = 3) -> list[str]:
    """Return the run's summary: p50/p99, mean legs of the tail, and its stalls.

    A stall: consecutive samples (gaps of at most ``stall_gap``) slower than ``stall_s`` or
    the p99, whichever is less; its first sample shows where the time went.
    """
    lat = run.latency
    p99 = float(np.percentile(lat, 99))
    legs = run.legs()
    slow = np.flatnonzero(lat >= p99)
    tail = ", ".join(f"{leg} {legs[leg][slow].mean() * 1e3:.2f}" for leg in LEGS)
    median = ", ".join(f"{leg} {np.median(legs[leg]) * 1e3:.2f}" for leg in LEGS)
    lines = [f"{run.label}: p50 {np.median(lat) * 1e3:.2f} ms, p99 {p99 * 1e3:.2f} ms, max "
             f"{lat.max() * 1e3:.2f} ms, > 2 ms: {np.count_nonzero(lat > 2e-3)} "
             f"(load {run.load}); GCs node {len(run.node_gc)}, client {len(run.client_gc)}",
             f"  median legs [ms]: {median}",
             f"  tail (>= p99, {len(slow)} samples) mean legs [ms]: {tail}",
             f"  first {FIRST} set points: p99 {np.percentile(lat[:FIRST], 99) * 1e3:.2f} ms, "
             f"max {lat[:FIRST].max() * 1e3:.2f}; the rest: p99 "
             f"{np.percentile(lat[FIRST:], 99) * 1e3:.2f}, max {lat[FIRST:].max() * 1e3:.2f}",
             "  client publish behind its schedule [ms]: "
             + late_summary(run.sent - (run.sent[0] + np.arange(len(run.sent)) / rate_hz)),
             "  node GCs during the run: " + gc_summary(run.node_gc, run.sent[0], run.received[-1]),
             "  node per message: " + ", ".join(f"{key} {value:.3g}" for key, value in
                                                run.node_proc.items())]
    slow = np.flatnonzero(lat >= min(p99, stall_s))
    groups = np.split(slow, np.flatnonzero(np.diff(slow) > stall_gap) + 1) if len(slow) else []
    for group in groups:
        k = int(group[0])
        first = ", ".join(f"{leg} {legs[leg][k] * 1e3:.2f}" for leg in LEGS)
        window = (run.sent[k] - 0.005, run.received[group[-1]])
        node = [*overlapping(run.node_gc, *window, "gen"),
                *overlapping(run.node_timer, *window, "timer")]
        client = overlapping(run.client_gc, *window, "gen")
        machine = overlapping(run.machine, *window, "late")
        lines.append(f"  stall at sample {k} ({(run.sent[k] - run.sent[0]):.3f} s), "
                     f"{len(group)} slow, worst {lat[group].max() * 1e3:.2f} ms; first: "
                     f"{first}; node {', '.join(node) or '-'}; client GC "
                     f"{', '.join(client) or '-'}; machine {', '.join(machine) or '-'}")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """Run the probed paced runs in turns and print each run's tail breakdown."""
    import common.benchlib  # noqa: F401  (the DDS environment of the benchmark)

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=128, help="rows = cols")
    parser.add_argument("--rate", type=float, default=1000.0, help="set points per second")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--kinds", nargs="+", default=["relay", "feedforward"],
                        choices=("relay", "feedforward"))
    parser.add_argument("--node-env", action="append", default=[], metavar="KEY=VALUE",
                        help="environment of the node processes (the B of an A/B)")
    parser.add_argument("--turns", action="store_true",
                        help="A/B: run each kind without and with --node-env in turns")
    parser.add_argument("--pause-ms", type=float, default=0.0,
                        help="stop the node (SIGSTOP) for this long half-way through each run")
    parser.add_argument("--log-dir", type=Path, default=Path("out/tail"))
    args = parser.parse_args(argv)
    shape = (args.grid, args.grid)
    variants = [("A", []), ("B", args.node_env)] if args.turns else [("", args.node_env)]
    p99: dict[str, list[float]] = {}
    for repeat in range(args.repeats):
        for kind in args.kinds:
            for tag, env in variants:
                name = f"{kind}{tag}"
                run = probed_run(kind, f"{name}_{repeat}", shape, rate_hz=args.rate,
                                 seconds=args.seconds, log_dir=args.log_dir, env=env,
                                 pause_s=args.pause_ms * 1e-3)
                p99.setdefault(name, []).append(float(np.percentile(run.latency, 99)) * 1e3)
                print("\n".join(report(run, args.rate)), flush=True)
    for name, values in p99.items():
        print(f"{name}: p99 per run [ms] {', '.join(f'{v:.2f}' for v in values)}")
    if args.node_env:
        print(f"B = node environment {' '.join(args.node_env)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
