"""The feedforward node at the largest grids in service: paced set points, p99, loss.

Issue 18's cases: 66 x 66 (4356, PALM-3000's grid) at 2 kHz, and 128 x 128 (16384) at 1 kHz.
The client (dds_client.DdsClient, one rclpy node in this process) streams set points at the
rate for a few seconds; the feedforward node and the floor, a plain relay of the same
message size on the same executor (the EventsExecutor the node uses), take turns, one
process start each per repeat. Unlike sections/feedforward.py's, a lost command is counted, not
an error: the loss is one of the figures.

    .venv/bin/python bench/bench_scale.py [--seconds 3] [--repeats 1]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from common.benchlib import Results, Settings
    from common.dds_client import DdsClient
    from hosttools.stall_witness import MachineCheck


#: (rows, cols, set-point rate [Hz], p99 target [ms], p99 target as a multiple of the relay's
#: p99, or None): the issue's figures.
SCALE_CASES: tuple[tuple[int, int, float, float, float | None], ...] = (
    (66, 66, 2000.0, 1.0, 1.2),
    (128, 128, 1000.0, 2.0, None),
)
#: Set points answered one at a time before each paced run (warm-up, not counted).
WARMUP = 50
#: Fewest set points of a paced run (the run is longer than ``--seconds`` if needed): its
#: p99 is its 1 %-worst, so that one stall of the machine of a few tens of ms (tens of late
#: set points) is not the p99 alone.
PACED_SAMPLES = 10_000
#: The node under test and its floor (bench/common/relay.py on the EventsExecutor).
KINDS = ("relay_events", "feedforward")


@dataclass(frozen=True)
class PacedRun:
    """Figures of one paced run.

    Attributes:
        sent: set points published.
        received: commands received back.
        sent_rate_hz: rate the set points went out at.
        received_rate_hz: commands received per second (first set point to last command).
        p50_s / p99_s: set-point-to-command latency percentiles [s]; NaN when a command was
            lost (set points and commands are paired by order).

    """

    sent: int
    received: int
    sent_rate_hz: float
    received_rate_hz: float
    p50_s: float
    p99_s: float

    @property
    def lost(self) -> int:
        """Set points without a command."""
        return self.sent - self.received


def paced_run(client: DdsClient, rate_hz: float, seconds: float) -> PacedRun:
    """Stream set points at ``rate_hz`` for ``seconds``; count what came back and time it."""
    first = client.received
    start = time.perf_counter()
    count = round(seconds * rate_hz)
    try:
        latencies, sent_rate, lost = client.paced(rate_hz, seconds)
    except RuntimeError:  # not every command came back within the client's drain time
        latencies, lost = None, count - (client.received - first)
    if latencies is None or lost:
        received = client.received - first
        last = client.received_at[-1] if received else time.perf_counter()
        return PacedRun(count, received, count / seconds, received / (last - start),
                        float("nan"), float("nan"))
    last = client.received_at[-1]
    return PacedRun(count, count, sent_rate, count / (last - start),
                    float(np.percentile(latencies, 50)), float(np.percentile(latencies, 99)))


def start_client(shape: tuple[int, int], timeout: float, hold_check: bool) -> DdsClient:
    """Return a DdsClient whose peer is up, has a temperature, and answered 50 set points.

    A feedforward node (``hold_check``) first gets the estimate and set points one at a time
    until a command shows it was taken.

    Raises:
        RuntimeError: the peer never showed up, or (``hold_check``) it answered 0 V only.

    """
    from common.dds_client import DdsClient

    client = DdsClient(shape)
    try:
        # the estimate is sent once the node's subscription matched (a volatile sample sent
        # before that is lost), and set points go until a command shows it was taken
        client.wait_for_peer(timeout=timeout, estimates=hold_check)
        if hold_check:
            client.use_temperature(timeout)
        client.latencies(WARMUP)  # one at a time
    except BaseException:
        client.close()
        raise
    return client


def node_command(kind: str, shape: tuple[int, int]) -> list[str]:
    """Return the argv of ``feedforward`` (its defaults) or ``relay_events``."""
    from common.benchlib import helper_command, launcher

    if kind == "relay_events":
        return helper_command("relay", "--ros-args", "-r", "__node:=relay", "-p",
                              "executor:=events")
    rows, cols = shape
    return [launcher("es_feedforward", "feedforward_node"), "--ros-args", "-p", f"rows:={rows}",
            "-p", f"cols:={cols}", "-p", "temperature_timeout:=0.0"]


@dataclass
class CaseRuns:
    """Paced runs of one node at one case, the machine's stalls in each, peak memory [MiB]."""

    runs: list[PacedRun] = field(default_factory=list)
    unanswered: list[float] = field(default_factory=list)
    checks: list[MachineCheck] = field(default_factory=list)
    peak_mib: float = 0.0

    def line(self, name: str) -> str:
        """Return the per-run figures: p99, slow set points and the machine's stalls."""
        def each(values: Sequence[float], spec: str = "g") -> str:
            return "[" + ", ".join(format(v, spec) for v in values) + "]"

        checks = self.checks
        return (f"{name}: p99 per run {each([r.p99_s * 1e3 for r in self.runs], '.3g')} ms; "
                f"slow (over the target) {each([c.slow for c in checks])} in "
                f"{each([c.episodes for c in checks])} episodes, of them after a stall of the "
                f"machine {each([c.slow_in_stall for c in checks])}; the machine's stalls "
                f"(>= half the target) {each([c.stalls for c in checks])}, longest "
                f"{each([c.longest_ms for c in checks], '.3g')} ms")


def published_commands(node_log: str) -> int | None:
    """Return the /dm/command count a node's exit summary logged (``None`` if it has none)."""
    import re

    match = re.search(r"published /dm/command: (\d+)", node_log)
    return int(match.group(1)) if match else None


def measure(kind: str, shape: tuple[int, int], rate_hz: float, seconds: float,
            log_dir: Path, *, target_s: float,
            ) -> tuple[PacedRun, float, int | None, MachineCheck]:
    """Start the node ``kind`` and a stall witness per CPU, run one paced measurement.

    Returns:
        The run, the node's peak RSS [MiB], how many of the paced set points the
        feedforward node never answered (from the count of published commands in its exit
        summary; the rest of ``PacedRun.lost`` was lost on the way back to the client;
        ``None`` for the relay, whose plain publisher is not counted), and the set points
        slower than ``target_s`` beside the machine's stalls (hosttools.stall_witness).

    """
    from common.benchlib import Process, processes
    from hosttools.stall_witness import MachineCheck, load_all, witness_commands

    rows, cols = shape
    name = f"scale_{kind}_{rows}x{cols}"
    node = Process(name, node_command(kind, shape), log_dir)
    witnesses = witness_commands(log_dir / f"{name}_witness")
    for path, _ in witnesses:
        path.unlink(missing_ok=True)
    watching = [Process(path.stem, argv, log_dir) for path, argv in witnesses]
    with processes(node, *watching):
        client = start_client(shape, 60.0, hold_check=kind == "feedforward")
        answered_before = client.received  # warm-up and estimate check, one at a time
        try:
            run = paced_run(client, rate_hz, seconds)
            sent, received = client.paced_sent_at, client.paced_received_at
        finally:
            client.close()
        node.sample_rss()
        for witness in watching:
            witness.stop()
    published = published_commands(node.output()) if kind == "feedforward" else None
    unanswered = None if published is None else run.sent - (published - answered_before)
    witnessed = load_all([path for path, _ in witnesses])
    check = MachineCheck.of(sent, received, witnessed, target_s)
    return run, node.peak_mib, unanswered, check


def section_scale(settings: Settings, results: Results, log_dir: Path) -> None:
    """Paced p99, rate and loss at 66 x 66 / 2 kHz and 128 x 128 / 1 kHz, beside the relay."""
    from common.benchlib import Record, load_note

    durations = []
    for rows, cols, rate, target_ms, target_ratio in SCALE_CASES:
        n = rows * cols
        seconds = max(settings.dds_rate_seconds, PACED_SAMPLES / rate)
        durations.append(f"{seconds:g} s at {rate:g} Hz")
        by_kind = {kind: CaseRuns() for kind in KINDS}
        for _ in range(settings.repeats):
            for kind in KINDS:  # in turns: a change of the machine's load hits both alike
                run, peak, unanswered, check = measure(kind, (rows, cols), rate, seconds,
                                                       log_dir, target_s=target_ms * 1e-3)
                by_kind[kind].runs.append(run)
                by_kind[kind].unanswered.append(float("nan") if unanswered is None
                                                else unanswered)
                by_kind[kind].checks.append(check)
                by_kind[kind].peak_mib = max(by_kind[kind].peak_mib, peak)
        ff, relay = by_kind["feedforward"], by_kind["relay_events"]
        ff_p99 = [r.p99_s * 1e3 for r in ff.runs]
        relay_p99 = [r.p99_s * 1e3 for r in relay.runs]
        ratio = float(np.median(ff_p99)) / float(np.median(relay_p99))
        results.records.append(Record.of(f"scale_paced_latency_p99_{rate:g}Hz", n, ff_p99, "ms",
                                          ratio))
        results.records.append(Record.of(f"scale_paced_lost_{rate:g}Hz", n,
                                          [r.lost for r in ff.runs], "set points"))
        results.records.append(Record.of(f"scale_paced_unanswered_{rate:g}Hz", n,
                                          ff.unanswered, "set points"))
        results.records.append(Record.of(f"scale_paced_rate_{rate:g}Hz", n,
                                          [r.received_rate_hz for r in ff.runs], "Hz"))
        results.records.append(Record.of("peak_rss_feedforward", n, [ff.peak_mib], "MiB"))
        results.references.append(Record.of(f"relay_events_paced_latency_p99_{rate:g}Hz", n,
                                            relay_p99, "ms"))
        results.references.append(Record.of(f"relay_events_paced_lost_{rate:g}Hz", n,
                                            [r.lost for r in relay.runs], "set points"))
        results.references.append(Record.of(f"scale_sent_rate_{rate:g}Hz", n,
                                            [r.sent_rate_hz for r in ff.runs], "Hz"))
        results.notes.append(target_line(
            rows, cols, rate, p99_ms=float(np.median(ff_p99)), ratio=ratio,
            lost=sum(r.lost for r in ff.runs), target_ms=target_ms, target_ratio=target_ratio))
        for kind in KINDS:
            results.notes.append(by_kind[kind].line(f"{rows} x {cols} {kind}"))
    results.notes.append(
        f"scale_*: set points paced at the named rate ({', '.join(durations)}) per run, "
        f"after {WARMUP} answered one at a time (warm-up, not counted), "
        f"{settings.repeats} run(s), feedforward node and relay (EventsExecutor, the node's) "
        "started in turns; p99 set point published -> command received (NaN if any was lost); "
        "ratio = feedforward p99 / relay p99 (medians of the runs); scale_paced_lost: set "
        "points without a command at the client; scale_paced_unanswered: of those, the ones "
        "the node never answered (from its exit summary of published commands; the rest were "
        "lost on the way back); per run: set points over the target, in episodes (a stall and "
        "its backlog), and how many were in episodes that began during a stall of the machine "
        "itself (one process per CPU beside the run that only sleeps 1 ms at a time woke at "
        "least half the target late: hosttools.stall_witness); "
        f"{load_note()}"
    )


def target_line(rows: int, cols: int, rate: float, *, p99_ms: float, ratio: float, lost: int,
                target_ms: float, target_ratio: float | None) -> str:
    """Return the one-line verdict of a case against the issue's targets."""
    ok = p99_ms <= target_ms and lost == 0 and (target_ratio is None or ratio <= target_ratio)
    wanted = f"p99 <= {target_ms:g} ms" + (
        f" and <= {target_ratio:g}x the relay" if target_ratio is not None else "")
    return (f"{'met' if ok else 'MISSED'}: {rows} x {cols} at {rate:g} Hz: {wanted}, nothing "
            f"lost (measured p99 {p99_ms:.3g} ms, {ratio:.2f}x the relay, {lost} lost)")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the scale section alone and print its records and notes."""
    from common.benchlib import Results, Settings

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0,
                        help=f"per paced run, at least {PACED_SAMPLES} set points' worth")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--log-dir", type=Path, default=Path("out/scale"))
    args = parser.parse_args(argv)
    settings = Settings.create(quick=True, profile=False)
    settings = type(settings)(**{**settings.__dict__, "repeats": args.repeats,
                                 "dds_rate_seconds": args.seconds})
    results = Results()
    section_scale(settings, results, args.log_dir)
    results.print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
