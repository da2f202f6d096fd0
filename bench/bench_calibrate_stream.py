"""Benchmark of the streamed calibration: wall time and peak RSS of ``calibrate`` on big bags.

Cases (issue 18, must-hold 2 and 3): 64 x 64 for 5 min at 500 Hz (goal <= 120 s, <= 2 GB),
64 x 64 for 1 min at 5 kHz (goal <= 2 GB), the first with 1 and 2 Dask workers, and 128 x 128
for 5 min at 500 Hz (and for 1 min, serial and with 1 and 2 workers); the first once more with
the effect search on the whole record (``--search-budget`` above the record's size; the default
searches windows of it, calibration/searchspan.py). Each calibration runs as its own process
under ``/usr/bin/time -v``: the peak RSS is that process's (with Dask, the driver's; the workers
are separate processes, their peak is not in it). The CPU time (user + system, with the
workers': /usr/bin/time counts the children the process waited for) says what Dask costs on a
machine where the wall time depends on the other users' load (and on Linux's autogroup
scheduling, which shares the CPU between sessions, not processes: extra worker processes get no
extra share on a loaded machine). Bags come from bench_calibrate's generator (synthetic law +
thermal expansion, 0.5 nm noise), cached in ``--bag-dir`` (they are big: about 32 KiB per
message at 64 x 64). The load average is printed with every case (a shared machine). Run:

    .venv/bin/python bench/bench_calibrate_stream.py --bag-dir /tmp/calbags [--cases NAME ...]

Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final, NamedTuple

from bench_calibrate import write_measured_bag

if TYPE_CHECKING:
    from common.benchlib import Results, Settings

#: Search budget of the case that searches the whole record (more than any case's values).
WHOLE: Final = 10**12


class Case(NamedTuple):
    """A case: grid edge, duration [s], rate [Hz], Dask workers (None: serial), budget."""

    edge: int
    duration: float
    rate: float
    workers: int | None = None
    search_budget: int | None = None  # None: the tool's default (calibration/searchspan.py)


CASES: Final = {
    "64x64_5min_500Hz": Case(64, 300.0, 500.0),
    "64x64_5min_500Hz_whole_search": Case(64, 300.0, 500.0, search_budget=WHOLE),
    "64x64_1min_5kHz": Case(64, 60.0, 5000.0),
    "64x64_5min_500Hz_1worker": Case(64, 300.0, 500.0, 1),
    "64x64_5min_500Hz_2workers": Case(64, 300.0, 500.0, 2),
    "128x128_5min_500Hz": Case(128, 300.0, 500.0),
    "64x64_1min_500Hz_serial": Case(64, 60.0, 500.0),
    "64x64_1min_500Hz_1worker": Case(64, 60.0, 500.0, 1),
    "64x64_1min_500Hz_2workers": Case(64, 60.0, 500.0, 2),
    "128x128_1min_500Hz": Case(128, 60.0, 500.0),
    # the tiles' refit is a few seconds of CPU at 64 x 64, less than a cluster's start
    "128x128_1min_500Hz_1worker": Case(128, 60.0, 500.0, 1),
    "128x128_1min_500Hz_2workers": Case(128, 60.0, 500.0, 2),
}
#: Smaller cases for a quick run (same shapes of work).
QUICK_CASES: Final = {
    "32x32_30s_500Hz": Case(32, 30.0, 500.0),
    "32x32_30s_500Hz_2workers": Case(32, 30.0, 500.0, 2),
}
_RSS = re.compile(r"Maximum resident set size \(kbytes\): (\d+)")
_CPU = re.compile(r"(?:User|System) time \(seconds\): ([\d.]+)")


@dataclass(frozen=True)
class StreamRun:
    """One measured calibration process."""

    name: str
    actuators: int
    wall_s: float
    peak_rss_mb: float
    cpu_s: float
    bag_gb: float
    load_before: float
    load_after: float
    status: int
    steps: str


def bag_for(bag_dir: Path, edge: int, duration: float, rate: float) -> Path:
    """Return the cached bag of a case, generating it first when missing."""
    bag = bag_dir / f"bag-{edge}x{edge}-{duration:g}s-{rate:g}Hz"
    if not (bag / "metadata.yaml").is_file():
        shutil.rmtree(bag, ignore_errors=True)
        bag_dir.mkdir(parents=True, exist_ok=True)
        write_measured_bag(bag, edge, edge, duration, rate)
    return bag


def measure(name: str, bag: Path, edge: int, workers: int | None, tile: int, *,
            search_budget: int | None = None) -> StreamRun:
    """Run ``calibrate`` on ``bag`` in a child under /usr/bin/time -v; return its figures.

    ``search_budget`` None: the tool's default (calibration/searchspan.py).
    """
    exe = Path(sys.executable).with_name("es_calibration-calibrate")
    with tempfile.TemporaryDirectory(prefix="bench_stream_") as out:
        cmd = ["/usr/bin/time", "-v", str(exe), str(bag), "-o", out, "-q", "--tile", str(tile)]
        if workers:
            cmd += ["--workers", str(workers)]
        if search_budget is not None:
            cmd += ["--search-budget", str(search_budget)]
        load_before = os.getloadavg()[0]
        start = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        wall = time.perf_counter() - start
        doc = Path(out) / "calibration.json"
        timings = json.loads(doc.read_text())["timings_s"] if doc.is_file() else {}
    found = _RSS.search(proc.stderr)
    if proc.returncode != 0:
        print(proc.stderr[-2000:], file=sys.stderr)
    size = sum(f.stat().st_size for f in bag.iterdir()) / 1e9
    times = _CPU.findall(proc.stderr)
    cpu = sum(float(v) for v in times) if times else float("nan")
    return StreamRun(name, edge * edge, wall, int(found.group(1)) / 1024 if found else float("nan"),
                     cpu, size, load_before, os.getloadavg()[0], proc.returncode,
                     ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()))


def run_cases(names: list[str], bag_dir: Path, tile: int, quick: bool = False) -> list[StreamRun]:
    """Measure the named cases (bags generated as needed), printing each as it finishes."""
    table = QUICK_CASES if quick else CASES
    runs = []
    for name in names:
        case = table[name]
        bag = bag_for(bag_dir, case.edge, case.duration, case.rate)
        result = measure(name, bag, case.edge, case.workers, tile, search_budget=case.search_budget)
        print(line(result), flush=True)
        runs.append(result)
    return runs


def line(r: StreamRun) -> str:
    """Return one readable line of a run."""
    return (f"calibrate {r.name}: {r.wall_s:.1f} s, CPU {r.cpu_s:.1f} s, peak RSS "
            f"{r.peak_rss_mb:.0f} MB, bag "
            f"{r.bag_gb:.1f} GB, exit {r.status}, load average {r.load_before:.1f} -> "
            f"{r.load_after:.1f} (2 cores); steps: {r.steps}")


def section_calibrate_stream(settings: Settings, results: Results) -> None:
    """bench/run.py section: the quick cases with --quick, else the issue's cases."""
    from common.benchlib import Record

    quick = settings.repeats == 1
    names = list(QUICK_CASES if quick else CASES)
    with tempfile.TemporaryDirectory(prefix="bench_stream_bags_") as bag_dir:
        for r in run_cases(names, Path(bag_dir), 16, quick):
            results.records.append(Record.of(f"calibrate_stream_time_{r.name}", r.actuators,
                                              [r.wall_s], "s"))
            results.records.append(Record.of(f"calibrate_stream_cpu_{r.name}", r.actuators,
                                              [r.cpu_s], "s"))
            results.records.append(Record.of(f"calibrate_stream_rss_{r.name}", r.actuators,
                                              [r.peak_rss_mb], "MB"))
            results.notes.append(line(r))


def main() -> None:
    """Run the chosen cases and print their figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bag-dir", type=Path, required=True, help="bag cache directory")
    parser.add_argument("--cases", nargs="+", choices=[*CASES, *QUICK_CASES], default=list(CASES))
    parser.add_argument("--tile", type=int, default=16)
    args = parser.parse_args()
    quick = all(name in QUICK_CASES for name in args.cases)
    run_cases(args.cases, args.bag_dir, args.tile, quick)


if __name__ == "__main__":
    main()
