"""The node graph across two hosts: set points from one, feedforward commands from the other.

Two network namespaces joined by a veth pair stand for two machines (hosttools.multihost); Fast DDS
finds the peers from an initial-peers profile, over UDP only. The benchmark client (the
dds_client DdsClient) runs on host A and streams paced set points; the feedforward node (or the
plain relay, the floor) runs on host B with the same parameters as in the feedforward
section; every command comes back across the link. Reported: rate of commands received,
p99 set-point-to-command, loss, and the bytes the link carried.

    .venv/bin/python bench/bench_multihost.py [--rows 64 --cols 64 --rate 1000 --seconds 5]

needs root (network namespaces). ``client`` is the part that runs inside host A.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from bench_scale import (
    KINDS,
    PacedRun,
    node_command,
    paced_run,
    start_client,
)
from common.benchlib import load_note
from hosttools.multihost import Host, host_environment, two_hosts

if TYPE_CHECKING:
    from common.benchlib import Results, Settings

#: The issue's case: 64 x 64 at 1 kHz across the link.
MULTIHOST_SHAPE = (64, 64)
MULTIHOST_RATE = 1000.0
#: Prefix of the client's one result line.
RESULT_PREFIX = "MULTIHOST_RESULT "
#: Longest wait for the peer on the other host to show up [s] (discovery over the link).
PEER_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class LinkRun:
    """A paced run across the link (bench_scale.PacedRun) and the bytes the link carried.

    ``link_bytes``: bytes host B's end of the link received plus sent during the whole run
    (discovery and warm-up included); 0 when both processes ran on one host.
    """

    run: PacedRun
    link_bytes: int = 0


def run_client(shape: tuple[int, int], rate_hz: float, seconds: float,
               hold_check: bool) -> PacedRun:
    """Stream paced set points to the peer node and time its commands (runs on host A).

    Raises:
        RuntimeError: the peer never showed up, or (``hold_check``) it answered 0 V only.

    """
    client = start_client(shape, PEER_TIMEOUT_S, hold_check)
    try:
        return paced_run(client, rate_hz, seconds)
    finally:
        client.close()


def measure_across(kind: str, shape: tuple[int, int], rate_hz: float, seconds: float,
                   log_dir: Path) -> LinkRun:
    """Run the node ``kind`` on host B and the client on host A; return the client's figures.

    Raises:
        multihost.NetnsError: the namespaces cannot be made.
        RuntimeError: the client failed or printed no result.

    """
    with two_hosts() as (host_a, host_b):
        before = _link_total(host_b)
        run = _client_and_node(
            kind, shape, rate_hz, seconds, log_dir,
            on_b=lambda argv: host_b.command(argv, host_environment(log_dir, 0, host_b.address)),
            on_a=lambda argv: host_a.command(argv, host_environment(log_dir, 1, host_a.address)))
        return LinkRun(run, _link_total(host_b) - before)


def measure_local(kind: str, shape: tuple[int, int], rate_hz: float, seconds: float,
                  log_dir: Path) -> LinkRun:
    """Run the same measurement with both processes on this host (localhost, shared memory).

    Raises:
        RuntimeError: the client failed or printed no result.

    """
    return LinkRun(_client_and_node(kind, shape, rate_hz, seconds, log_dir, on_b=list,
                                    on_a=list))


def _client_and_node(kind: str, shape: tuple[int, int], rate_hz: float, seconds: float,
                     log_dir: Path, *, on_b: Callable[[list[str]], list[str]],
                     on_a: Callable[[list[str]], list[str]]) -> PacedRun:
    from common.benchlib import Process, processes

    rows, cols = shape
    node = Process(f"multihost_{kind}_{rows}x{cols}", on_b(node_command(kind, shape)), log_dir)
    client_argv = [sys.executable, str(Path(__file__).resolve()), "client", "--rows",
                   str(rows), "--cols", str(cols), "--rate", str(rate_hz), "--seconds",
                   str(seconds), *(["--hold-check"] if kind == "feedforward" else [])]
    client = Process(f"multihost_client_{kind}_{rows}x{cols}", on_a(client_argv), log_dir)
    with processes(node, client):
        client.popen.wait(PEER_TIMEOUT_S + 4 * seconds + 60.0)
    return parse_result(client.output())


def _link_total(host: Host) -> int:
    received, sent = host.link_bytes()
    return received + sent


def section_multihost(settings: Settings, results: Results, log_dir: Path) -> None:
    """Rate, p99 and loss of set points -> commands across the link at 64 x 64 and 1 kHz.

    Per repeat, in turns: the relay across the link, the feedforward node across the link,
    and the feedforward node with its client on one host (the single-host reference).

    Raises:
        multihost.NetnsError: the namespaces cannot be made (not root).

    """
    from common.benchlib import Record

    rows, cols = MULTIHOST_SHAPE
    n = rows * cols
    seconds = max(settings.dds_rate_seconds, 3.0)
    across: dict[str, list[LinkRun]] = {kind: [] for kind in KINDS}
    local: list[LinkRun] = []
    for _ in range(settings.repeats):
        for kind in KINDS:
            across[kind].append(measure_across(kind, MULTIHOST_SHAPE, MULTIHOST_RATE, seconds,
                                               log_dir))
        local.append(measure_local("feedforward", MULTIHOST_SHAPE, MULTIHOST_RATE, seconds,
                                   log_dir))
    ff = [link.run for link in across["feedforward"]]
    p99 = [r.p99_s * 1e3 for r in ff]
    local_p99 = [link.run.p99_s * 1e3 for link in local]
    results.records.append(Record.of("multihost_paced_latency_p99", n, p99, "ms",
                                      float(np.median(p99)) / float(np.median(local_p99))))
    results.records.append(Record.of("multihost_paced_latency_p50", n,
                                      [r.p50_s * 1e3 for r in ff], "ms"))
    results.records.append(Record.of("multihost_paced_rate", n, [r.received_rate_hz for r in ff],
                                      "Hz"))
    results.records.append(Record.of("multihost_paced_lost", n, [r.lost for r in ff],
                                      "set points"))
    results.records.append(Record.of(
        "multihost_link_bytes_per_setpoint", n,
        [link.link_bytes / link.run.sent for link in across["feedforward"]], "B"))
    results.references.append(Record.of(
        "multihost_relay_paced_latency_p99", n,
        [link.run.p99_s * 1e3 for link in across["relay_events"]], "ms"))
    results.references.append(Record.of(
        "multihost_relay_paced_lost", n, [link.run.lost for link in across["relay_events"]],
        "set points"))
    results.references.append(Record.of("local_feedforward_paced_latency_p99", n, local_p99,
                                        "ms"))
    results.references.append(Record.of("local_feedforward_paced_lost", n,
                                        [link.run.lost for link in local], "set points"))
    results.notes.append(
        f"multihost_*: {rows} x {cols} set points paced at {MULTIHOST_RATE:g} Hz for "
        f"{seconds:g} s from host A to the feedforward node on host B, commands back; the "
        "hosts are two network namespaces joined by a veth pair (MTU 1500), Fast DDS over "
        "UDPv4 only with initial peers (hosttools.multihost, docs/scaling.md's recipe); ratio = "
        "p99 across the link / p99 of the same client and node on one host (shared memory, "
        "local_feedforward_*); multihost_relay_*: the relay (EventsExecutor) across the link; "
        "link_bytes_per_setpoint: bytes through host B's end of the link (both directions, "
        f"discovery and warm-up included) per set point sent. {load_note()}"
    )


def parse_result(output: str) -> PacedRun:
    """Return the :class:`PacedRun` the client printed.

    Raises:
        RuntimeError: no result line (the client's last output is in the message).

    """
    for line in reversed(output.splitlines()):
        if line.startswith(RESULT_PREFIX):
            return PacedRun(**json.loads(line[len(RESULT_PREFIX):]))
    tail = output.strip().splitlines()[-3:]
    raise RuntimeError("the client on host A printed no result: " + " | ".join(tail))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the client (``client``) or one measurement across a fresh pair of hosts."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("role", nargs="?", choices=("measure", "client"), default="measure")
    parser.add_argument("--rows", type=int, default=64)
    parser.add_argument("--cols", type=int, default=64)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--kind", choices=KINDS, default="feedforward")
    parser.add_argument("--local", action="store_true",
                        help="both processes on this host (the single-host reference)")
    parser.add_argument("--hold-check", action="store_true")
    parser.add_argument("--log-dir", type=Path, default=Path("out/multihost"))
    args = parser.parse_args(argv)
    shape = (args.rows, args.cols)
    if args.role == "client":
        run = run_client(shape, args.rate, args.seconds, args.hold_check)
        print(RESULT_PREFIX + json.dumps(asdict(run)), flush=True)
        return 0
    measure = measure_local if args.local else measure_across
    try:
        link = measure(args.kind, shape, args.rate, args.seconds, args.log_dir)
    except RuntimeError as err:  # NetnsError included: one readable line, exit 1
        print(f"bench_multihost: {err}", file=sys.stderr)
        return 1
    print(json.dumps({**asdict(link.run), "lost": link.run.lost, "link_bytes": link.link_bytes}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
