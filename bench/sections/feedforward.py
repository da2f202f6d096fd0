"""Section ``feedforward``: the feedforward node over DDS against a plain rclpy relay."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from common.benchlib import (
    Context,
    Process,
    Record,
    Results,
    Settings,
    helper_command,
    launcher,
    processes,
    top_of,
)
from common.dds_client import PACED_RATE, RATE_WINDOW, DdsClient

#: Grid shapes of the DDS benchmark (N = 144, 1024, 4096).
DDS_SHAPES = ((12, 12), (32, 32), (64, 64))


@dataclass
class DdsRun:
    """Figures of one node (feedforward or relay) at one grid size, one per repeat."""

    rate_hz: list[float] = field(default_factory=list)
    p50_s: list[float] = field(default_factory=list)
    p99_s: list[float] = field(default_factory=list)
    paced_p99_s: list[float] = field(default_factory=list)
    paced_rate_hz: list[float] = field(default_factory=list)
    #: commands that never came back, per repeat (rate and paced runs)
    lost: list[int] = field(default_factory=list)
    peak_mib: float = 0.0

    def add(self, other: DdsRun) -> None:
        """Append the figures of ``other`` (another repeat); keep the larger peak memory."""
        self.rate_hz += other.rate_hz
        self.p50_s += other.p50_s
        self.p99_s += other.p99_s
        self.paced_p99_s += other.paced_p99_s
        self.paced_rate_hz += other.paced_rate_hz
        self.lost += other.lost
        self.peak_mib = max(self.peak_mib, other.peak_mib)


def _measure_node(kind: str, shape: tuple[int, int], settings: Settings, log_dir: Path,
                  profile_to: Path | None = None) -> DdsRun:
    rows, cols = shape
    if kind in ("relay", "relay_events"):
        executor = "events" if kind == "relay_events" else "single_threaded"
        command = helper_command("relay", "--ros-args", "-r", "__node:=relay", "-p",
                                 f"executor:={executor}")
    else:
        args = ["--ros-args", "-p", f"rows:={rows}", "-p", f"cols:={cols}",
                "-p", "temperature_timeout:=0.0"]
        command = (
            [sys.executable, "-m", "cProfile", "-o", str(profile_to), "-m",
             "es_feedforward.feedforward_node", *args]
            if profile_to is not None
            else [launcher("es_feedforward", "feedforward_node"), *args]
        )
    run = DdsRun()
    client = DdsClient(shape)
    node = Process(f"{kind}_{rows}x{cols}" + ("_profiled" if profile_to else ""), command,
                   log_dir)
    try:
        with processes(node):
            client.wait_for_peer(estimates=kind == "feedforward")
            if kind == "feedforward":
                client.use_temperature()
            client.latencies(200)  # warm-up
            for _ in range(settings.repeats):
                lat = client.latencies(settings.dds_latency_samples)
                run.p50_s.append(float(np.percentile(lat, 50)))
                run.p99_s.append(float(np.percentile(lat, 99)))
                rate, lost = client.rate(settings.dds_rate_seconds)
                run.rate_hz.append(rate)
                paced, sent_rate, paced_lost = client.paced(PACED_RATE, settings.dds_rate_seconds)
                if paced is not None:
                    run.paced_p99_s.append(float(np.percentile(paced, 99)))
                run.paced_rate_hz.append(sent_rate)
                run.lost.append(lost + paced_lost)
                node.sample_rss()
            run.peak_mib = node.peak_mib
    finally:
        client.close()
    return run


def run(context: Context) -> None:
    """Feedforward node vs a plain relay over DDS: rate, p50/p99 latency, peak memory."""
    settings, results, log_dir = context.settings, context.results, context.log_dir
    for shape in DDS_SHAPES:
        n = shape[0] * shape[1]
        # Relay and node take turns, one process start each per repeat, so that a change of
        # the machine's load during the section hits both alike.
        relay, ff, relay_events = DdsRun(), DdsRun(), DdsRun()
        kinds = [("relay", relay), ("feedforward", ff)]
        if shape == DDS_SHAPES[-1]:  # what the relay costs on the feedforward's executor
            kinds.append(("relay_events", relay_events))
        one = replace(settings, repeats=1)
        for _ in range(settings.repeats):
            for kind, total in kinds:
                total.add(_measure_node(kind, shape, one, log_dir))
        relay_rate = float(np.median(relay.rate_hz))
        results.records.append(Record.of("feedforward_rate", n, ff.rate_hz, "Hz",
                                          float(np.median(ff.rate_hz)) / relay_rate))
        for label, ff_values, relay_values in (("p50", ff.p50_s, relay.p50_s),
                                               ("p99", ff.p99_s, relay.p99_s)):
            ms = [v * 1e3 for v in ff_values]
            results.records.append(Record.of(
                f"feedforward_latency_{label}", n, ms, "ms",
                float(np.median(ff_values)) / float(np.median(relay_values))))
            results.references.append(Record.of(f"relay_latency_{label}", n,
                                                [v * 1e3 for v in relay_values], "ms"))
        if ff.paced_p99_s and relay.paced_p99_s:  # none when commands were lost
            results.records.append(Record.of(
                "feedforward_paced_latency_p99", n, [v * 1e3 for v in ff.paced_p99_s], "ms",
                float(np.median(ff.paced_p99_s)) / float(np.median(relay.paced_p99_s))))
        results.records.append(Record.of("feedforward_lost", n, ff.lost, "commands"))
        results.references.append(Record.of("relay_lost", n, relay.lost, "commands"))
        results.references.append(Record.of("feedforward_paced_rate", n, ff.paced_rate_hz,
                                            "Hz"))
        if relay.paced_p99_s:
            results.references.append(Record.of("relay_paced_latency_p99", n,
                                                [v * 1e3 for v in relay.paced_p99_s], "ms"))
        results.references.append(Record.of("relay_rate", n, relay.rate_hz, "Hz"))
        if relay_events.rate_hz:
            results.references.append(Record.of("relay_events_rate", n, relay_events.rate_hz,
                                                "Hz"))
        results.records.append(Record.of("peak_rss_feedforward", n, [ff.peak_mib], "MiB"))
        results.references.append(Record.of("peak_rss_relay", n, [relay.peak_mib], "MiB"))
    results.notes.append(
        "feedforward_*: relay and feedforward processes started in turns, one measurement "
        "each per repeat; feedforward_rate: commands per second with "
        f"{RATE_WINDOW} set points in flight (ratio = feedforward / relay, same message size, "
        "same run); latency: set point published -> command received in the client, one at "
        "a time (ratio = feedforward / relay); paced_latency_p99: the same while set points "
        f"stream at {PACED_RATE:g} Hz for as long as the rate run (feedforward_paced_rate: the "
        "rate the client achieved). The relay runs on rclpy's default "
        "SingleThreadedExecutor, the feedforward node on the EventsExecutor (its default); "
        "relay_events_rate is the relay on the EventsExecutor too. The client is one rclpy "
        "node in the benchmark process; its own cost is in all figures alike."
    )
    if settings.profile:
        _profile_feedforward(results, log_dir)


def _profile_feedforward(results: Results, log_dir: Path) -> None:
    """CProfile of the feedforward node process while it serves set points at 64 x 64."""
    profile = log_dir / "feedforward_64x64.prof"
    quick = Settings.create(quick=True, profile=False)
    _measure_node("feedforward", DDS_SHAPES[-1], quick, log_dir, profile_to=profile)
    results.profiles["feedforward node at 64 x 64, serving set points"] = top_of(profile)
