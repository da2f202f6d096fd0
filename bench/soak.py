"""Soak: the closed loop in real time for a long run, recorder on; counts, memory, diagnostics.

Usage (from the repository root; ``scripts/soak`` bootstraps the venv and calls this)::

    .venv/bin/python bench/soak.py [--minutes M] [-o OUT] [--keep-bag]

Runs ``bringup`` on ``dm_exposure`` (12 x 12, 100 Hz) with ``lockstep:=false`` (the plant
free-runs on the wall clock) and ``duration`` M minutes of sim time, recorder on, and checks:

- counts: for every /dm topic, published (the nodes' exit logs) == received and written
  (the recorder's exit log) == messages in the bag, and no loss reported by the middleware;
- memory: every node's resident set (VmRSS of ``/proc/<pid>/status``, sampled every
  ``--sample-s`` seconds) grows by less than ``--max-growth`` between the first and the last
  minute after the warm-up (``--warmup-minutes``, default a sixth of the run, at most 5);
- diagnostics: no ERROR status in the recorded /diagnostics once the plant's clock runs
  (the ones before, while the controllers wait for the plant, are listed apart).

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
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from es_msgs_py.topics import process_domain_id

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(process_domain_id()))
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
    """Run the real-time graph; return (exit code, memory per node, bringup output, wall s)."""
    from es_sim_plant.bringup import executable

    command = [
        str(executable("es_sim_plant", "bringup")),
        "--scenario", SCENARIO,
        "--bag", str(out / "bag"),
        "--log-dir", str(out / "logs"),
        "--quiet",
        "--timeout", str(minutes * 60.0 + 300.0),
        "--plant-param", "lockstep:=false",
        "--plant-param", f"duration:={minutes * 60.0}",
    ]  # fmt: skip
    memory: dict[str, NodeMemory] = {}
    lines: list[str] = []
    start = time.monotonic()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)

    def read_output() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            match = _STARTED.search(line)
            if match:
                memory[match.group(1)] = NodeMemory(int(match.group(2)))

    reader = threading.Thread(target=read_output, daemon=True)
    reader.start()
    try:
        while proc.poll() is None:
            now = time.monotonic() - start
            for node in list(memory.values()):
                value = rss_mib(node.pid)
                if value is not None:
                    node.samples.append((now, value))
            time.sleep(sample_s)
    except KeyboardInterrupt:
        proc.terminate()  # bringup stops its nodes one by one, the recorder last
        proc.wait()
        raise
    reader.join(timeout=10.0)
    return proc.returncode, memory, lines, time.monotonic() - start


def check_counts(bag: Path, log_dir: Path) -> tuple[dict[str, dict[str, int]], list[str]]:
    """Compare published, received, written and bagged counts of every /dm topic.

    One topic at a time is read from the bag (a long run's bag does not fit comfortably in
    memory at once).
    """
    from es_msgs_py import topics
    from es_msgs_py.bag import BagError, read_bag
    from es_sim_plant.analysis import node_logs
    from es_sim_plant.invariants import published_counts_from_log, recorder_counts_from_log

    logs = node_logs(log_dir)
    published: dict[str, int] = {}
    for node, lines in logs.items():
        if node == "record":
            continue
        for topic, count in published_counts_from_log(lines, tuple(topics.TOPIC_TYPES)).items():
            published[topic] = published.get(topic, 0) + count
    recorder = recorder_counts_from_log(logs.get("record", []))
    figures: dict[str, dict[str, int]] = {}
    failures: list[str] = []
    for topic in topics.DM_TOPICS:
        try:
            series = read_bag(bag, [topic]).get(topic)
        except BagError as err:
            failures.append(f"{topic}: bag unreadable: {err}")
            continue
        in_bag = 0 if series is None else len(series)
        received, written, lost = recorder.get(topic, (0, 0, 0))
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
    return figures, failures


def diagnostic_errors(bag: Path) -> tuple[dict[str, int], dict[str, int]]:
    """Count ERROR statuses in the recorded /diagnostics by ``<status name>: <message>``.

    Returns (start-up, run): start-up ones were recorded before the plant's clock ran (bag
    time 0: the recorder uses sim time), while the controllers waited for the plant, which
    the bring-up starts last; every other one is an error of the run.
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
        errors = startup if stamp <= 0.0 else run
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
              "", "diagnostic ERRORs at start-up (before the plant's clock ran): "
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
        counts, count_failures = check_counts(bag, out / "logs")
        failures += count_failures
        startup_errors, errors = diagnostic_errors(bag)
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
