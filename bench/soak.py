"""Soak: the closed loop in real time for a long run, recorder on; counts, memory, diagnostics.

Usage (from the repository root; ``scripts/soak`` bootstraps the venv and calls this)::

    .venv/bin/python bench/soak.py [--minutes M] [-o OUT] [--keep-bag]

Runs the bring-up's graph on ``dm_exposure`` (12 x 12, 100 Hz) below its own namespace with
``lockstep: false`` (the plant free-runs on the wall clock) and ``duration`` M minutes of sim
time, recorder on, and checks:

- counts: for every /dm topic, published (the nodes' exit logs) == received and written
  (the recorder's exit log) == messages in the bag, and no loss reported by the middleware;
- memory: every node's resident set (VmRSS of ``/proc/<pid>/status``, sampled every
  ``--sample-s`` seconds) grows by less than ``--max-growth`` between the first and the last
  minute after the warm-up (``--warmup-minutes``, default a sixth of the run, at most 5);
- diagnostics: no ERROR status in the recorded /diagnostics between the plant's first and
  last step (the ones before and after, while the controllers wait for the plant or it has
  finished, are listed apart).

Writes ``soak.json`` (settings, figures, RSS samples, failures) and ``soak.md`` into OUT
(default ``out/soak-<UTC timestamp>``); the bag is deleted afterwards unless ``--keep-bag``
(30 minutes are about 0.7 GB). Exits 0 when everything held, 1 otherwise. Not part of the
test suite: it is a benchmark of how the graph holds up over time.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import re
import shutil
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from es_msgs_py.topics import reserve_domain_id

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
# a domain no other es_dm process here holds (a test run beside the benchmark, say)
if not os.environ.get("ROS_DOMAIN_ID"):
    os.environ["ROS_DOMAIN_ID"] = str(reserve_domain_id())
os.environ.setdefault("PYTHONUNBUFFERED", "1")

SCENARIO = "dm_exposure"
#: Supervisor announcement of a started node (bringup's stderr).
_STARTED = re.compile(r"started (\w+) \(pid (\d+)\)")
#: Seconds of RSS samples averaged at each end of the measured window.
WINDOW_S = 60.0


@dataclass
class NodeMemory:
    """RSS samples of one node process: (seconds since the run started, MiB)."""

    pid: int
    samples: list[tuple[float, float]] = field(default_factory=list)

    def growth(self, warmup_s: float) -> tuple[float, float, float] | None:
        """Return (baseline MiB, final MiB, growth fraction) after ``warmup_s``.

        Baseline: mean of the samples in the first ``WINDOW_S`` after the warm-up; final: mean
        of the samples in the last ``WINDOW_S``. ``None`` when there are no samples after the
        warm-up.
        """
        after = [(t, v) for t, v in self.samples if t >= warmup_s]
        if not after:
            return None
        first = [v for t, v in after if t < after[0][0] + WINDOW_S]
        last = [v for t, v in after if t > after[-1][0] - WINDOW_S]
        baseline = sum(first) / len(first)
        final = sum(last) / len(last)
        return baseline, final, final / baseline - 1.0


def rss_mib(pid: int) -> float | None:
    """Return the resident set (VmRSS) of a live process [MiB], or ``None`` if it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def run_bringup(
    minutes: float, out: Path, sample_s: float
) -> tuple[int, dict[str, NodeMemory], list[str], float]:
    """Run the real-time graph; return (exit code, memory per node, bring-up lines, wall s).

    The graph runs below its own namespace (``soak<pid>``): whatever else shares the ROS
    domain (another test's plant, say) cannot publish into it.
    """
    from es_bringup.bringup import Bringup, GraphConfig

    config = GraphConfig(
        scenario=SCENARIO,
        bag=out / "bag",
        log_dir=out / "logs",
        plant={"lockstep": False, "duration": minutes * 60.0},
        namespace=f"soak{os.getpid()}",
        wall_timeout=minutes * 60.0 + 300.0,
    )
    memory: dict[str, NodeMemory] = {}
    lines: list[str] = []

    def announce(text: str) -> None:
        lines.append(text)
        print(f"[soak] {text}", file=sys.stderr, flush=True)
        match = _STARTED.search(text)
        if match:
            memory[match.group(1)] = NodeMemory(int(match.group(2)))

    bringup = Bringup(config, announce=announce)
    outcome: list[int] = []
    runner = threading.Thread(target=lambda: outcome.append(bringup.run().exit_code))
    start = time.monotonic()
    runner.start()
    try:
        while runner.is_alive():
            now = time.monotonic() - start
            for node in list(memory.values()):
                value = rss_mib(node.pid)
                if value is not None:
                    node.samples.append((now, value))
            runner.join(sample_s)
    except KeyboardInterrupt:
        bringup.interrupt()  # stops the nodes one by one, the recorder last
        runner.join()
        raise
    return (outcome[0] if outcome else 1), memory, lines, time.monotonic() - start


def check_counts(
    bag: Path, log_dir: Path
) -> tuple[dict[str, dict[str, int]], list[str], float]:
    """Compare published, received, written and bagged counts of every /dm topic.

    Returns (counts per topic, failures, bag time of the last /dm/displacement [s]). One
    topic at a time is read from the bag (a long run's bag does not fit comfortably in
    memory at once).
    """
    from es_bringup.analysis import node_logs
    from es_bringup.invariants import (
        RecorderCounts,
        contract_name,
        published_counts_from_log,
        recorder_counts_from_log,
    )
    from es_msgs_py import topics
    from es_msgs_py.bag import BagError, read_bag

    logs = node_logs(log_dir)
    names = tuple(topics.TOPIC_TYPES)
    published: dict[str, int] = {}
    for node, lines in logs.items():
        if node == "record":
            continue
        for topic, count in published_counts_from_log(lines, names).items():
            published[topic] = published.get(topic, 0) + count
    recorder = {contract_name(topic, names): counts
                for topic, counts in recorder_counts_from_log(logs.get("record", [])).items()}
    figures: dict[str, dict[str, int]] = {}
    failures: list[str] = []
    end = float("inf")
    for topic in topics.DM_TOPICS:
        try:
            series = read_bag(bag, [topic]).get(topic)
        except BagError as err:
            failures.append(f"{topic}: bag unreadable: {err}")
            continue
        in_bag = 0 if series is None else len(series)
        if topic == topics.DISPLACEMENT and in_bag:
            assert series is not None
            end = float(series.times[-1])
        received, written, lost, _ = recorder.get(topic, RecorderCounts(0, 0))
        sent = published.get(topic)
        figures[topic] = {
            "published": -1 if sent is None else sent,
            "received": received,
            "written": written,
            "lost": lost,
            "in_bag": in_bag,
        }
        if sent is None:
            failures.append(f"{topic}: no node reported a published count")
        elif not sent == received == written == in_bag or lost:
            failures.append(
                f"{topic}: published {sent}, received {received}, written {written}, "
                f"in the bag {in_bag}, lost {lost}"
            )
    return figures, failures, end


def diagnostic_errors(bag: Path, end: float) -> tuple[dict[str, int], dict[str, int]]:
    """Count ERROR statuses in the recorded /diagnostics by ``<status name>: <message>``.

    Returns (start-up and shut-down, run). The recorder stamps with sim time: bag time 0 is
    before the plant's clock ran (the controllers wait for the plant, which the bring-up
    starts last), ``end`` (the last displacement) and later is after its last step (the
    controllers hear nothing more while the bring-up stops them one by one). Every other
    ERROR is an error of the run.
    """
    from es_msgs_py import topics
    from es_msgs_py.bag import read_bag
    from es_msgs_py.diagnostics import Level, level_of

    startup: dict[str, int] = {}
    run: dict[str, int] = {}
    series = read_bag(bag, [topics.DIAGNOSTICS]).get(topics.DIAGNOSTICS)
    if series is None:
        return startup, run
    for stamp, message in zip(series.times, series.messages, strict=True):
        errors = startup if stamp <= 0.0 or stamp >= end else run
        for status in message.status:
            if level_of(status) == Level.ERROR:
                key = f"{status.name}: {status.message}"
                errors[key] = errors.get(key, 0) + 1
    return startup, run


def write_report(out: Path, result: Mapping[str, object]) -> None:
    """Write soak.json and a readable soak.md into ``out``."""
    (out / "soak.json").write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    lines = [f"# Soak {result['date']}", "", f"`{result['command']}`", ""]
    lines += ["| topic | published | received | written | in bag | lost |",
              "|---|---:|---:|---:|---:|---:|"]
    counts = result["counts"]
    assert isinstance(counts, dict)
    for topic, c in counts.items():
        lines.append(
            f"| {topic} | {c['published']} | {c['received']} | {c['written']} | "
            f"{c['in_bag']} | {c['lost']} |"
        )
    lines += ["", "| node | RSS after warm-up (MiB) | RSS at the end (MiB) | growth | samples |",
              "|---|---:|---:|---:|---:|"]
    memory = result["memory"]
    assert isinstance(memory, dict)
    for node, m in memory.items():
        lines.append(
            f"| {node} | {m['baseline_mib']:.1f} | {m['final_mib']:.1f} | "
            f"{100 * m['growth']:.2f} % | {m['samples']} |"
        )
    lines += ["", f"diagnostic ERRORs during the run: {result['diagnostic_errors'] or 'none'}",
              "", "diagnostic ERRORs before the plant's first step and after its last: "
              f"{result['startup_diagnostic_errors'] or 'none'}", ""]
    failures = result["failures"]
    assert isinstance(failures, list)
    lines += ["failures:" if failures else "everything held", *(f"- {f}" for f in failures)]
    (out / "soak.md").write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the soak, write its report, print a summary; exit 0 when everything held."""
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0, help="run length (sim = wall)")
    parser.add_argument("-o", "--output", type=Path, default=Path(f"out/soak-{stamp}"))
    parser.add_argument("--sample-s", type=float, default=5.0, help="RSS sampling period, s")
    parser.add_argument("--warmup-minutes", type=float, default=None,
                        help="memory growth is measured after this (default min(5, M/6))")
    parser.add_argument("--max-growth", type=float, default=0.05, help="memory growth limit")
    parser.add_argument("--keep-bag", action="store_true", help="keep the recorded bag")
    args = parser.parse_args(argv)
    if not 0.5 <= args.minutes <= 24 * 60:
        parser.error(f"--minutes must be in [0.5, 1440], got {args.minutes}")
    warmup_s = 60.0 * (min(5.0, args.minutes / 6) if args.warmup_minutes is None
                       else args.warmup_minutes)
    out: Path = args.output
    if out.exists():
        parser.error(f"{out} exists")
    out.mkdir(parents=True)
    load_start = os.getloadavg()[0]
    print(f"soak: {args.minutes:g} min of {SCENARIO} in real time into {out}", file=sys.stderr)
    code, memory, output, wall = run_bringup(args.minutes, out, args.sample_s)
    (out / "bringup.log").write_text("\n".join(output) + "\n", encoding="utf-8")
    failures = [] if code == 0 else [f"bringup exited {code}: {output[-1] if output else ''}"]
    bag = out / "bag"
    counts: dict[str, dict[str, int]] = {}
    errors: dict[str, int] = {}
    startup_errors: dict[str, int] = {}
    if bag.exists():
        counts, count_failures, end = check_counts(bag, out / "logs")
        failures += count_failures
        startup_errors, errors = diagnostic_errors(bag, end)
        failures += [f"diagnostic ERROR x{n}: {key}" for key, n in errors.items()]
    else:
        failures.append("no bag was written")
    figures: dict[str, dict[str, float | int]] = {}
    for node, mem in memory.items():
        growth = mem.growth(warmup_s)
        if growth is None:
            failures.append(f"{node}: no memory sample after the warm-up")
            continue
        baseline, final, fraction = growth
        figures[node] = {"baseline_mib": baseline, "final_mib": final, "growth": fraction,
                         "samples": len(mem.samples)}
        if fraction >= args.max_growth:
            failures.append(f"{node}: memory grew {100 * fraction:.1f} % "
                            f"({baseline:.1f} -> {final:.1f} MiB)")
    result = {
        "date": stamp,
        "command": " ".join(["bench/soak.py", *(argv if argv is not None else sys.argv[1:])]),
        "settings": {"minutes": args.minutes, "scenario": SCENARIO, "sample_s": args.sample_s,
                     "warmup_s": warmup_s, "max_growth": args.max_growth,
                     "load_average_start": load_start},
        "wall_s": wall,
        "counts": counts,
        "memory": figures,
        "rss_samples": {node: mem.samples for node, mem in memory.items()},
        "diagnostic_errors": errors,
        "startup_diagnostic_errors": startup_errors,
        "failures": failures,
    }
    write_report(out, result)
    if bag.exists() and not args.keep_bag:
        shutil.rmtree(bag)
    print((out / "soak.md").read_text(encoding="utf-8"))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
