"""Shared pieces of the benchmark sections: settings, records, node processes, waits.

Importing it sets the DDS environment of every benchmark run (localhost discovery, a
ROS_DOMAIN_ID of its own unless given, Fast DDS with the nodes' profile). The helpers that
run as processes of their own (relay, probe_node) are started with :func:`helper_command`.
"""

from __future__ import annotations

import io
import os
import platform
import pstats
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from es_msgs_py.topics import reserve_domain_id
from es_node_runtime.middleware import configure_middleware

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
# a domain no other es_dm process here holds (a test run beside the benchmark, say)
if not os.environ.get("ROS_DOMAIN_ID"):
    os.environ["ROS_DOMAIN_ID"] = str(reserve_domain_id())
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("PYTHONUNBUFFERED", "1")

import numpy as np

configure_middleware()  # the nodes' Fast DDS profile, for this process and its children
#: bench/: the folder of the ``common`` package, the benchmarks and their sections.
BENCH_DIR = Path(__file__).resolve().parents[1]



@dataclass(frozen=True)
class Settings:
    """How long and how often each section measures."""

    repeats: int
    kernel_sizes: tuple[int, ...]
    dds_rate_seconds: float
    dds_latency_samples: int
    lockstep_duration: float
    calibrate_small_duration: float
    calibrate_large_duration: float
    calibrate_rate: float
    profile: bool

    @classmethod
    def create(cls, quick: bool, profile: bool, calibrate_large: float | None = None) -> Settings:
        """Return the full settings (about 9 minutes here) or the quick ones (about 1.5).

        ``calibrate_large``: seconds of data of the 32 x 32 calibration case (default: the
        issue's 300 s, a 2.4 GB bag; quick: 10 s).
        """
        sizes = (1, 144, 1024, 4096, 16384)
        if quick:
            return cls(1, sizes, 1.5, 300, 5.0, 30.0, calibrate_large or 10.0, 500.0, False)
        return cls(3, sizes, 3.0, 1000, 30.0, 300.0, calibrate_large or 300.0, 500.0, profile)


@dataclass(frozen=True)
class Record:
    """One figure of bench.json: median of repeated runs, their min and max."""

    name: str
    n: int
    median: float
    min: float
    max: float
    unit: str
    ratio: float | None = None

    @classmethod
    def of(cls, name: str, n: int, samples: Sequence[float], unit: str,
           ratio: float | None = None) -> Record:
        """Summarise repeated measurements ``samples``."""
        values = np.asarray(samples, np.float64)
        return cls(name, n, float(np.median(values)), float(values.min()), float(values.max()),
                   unit, None if ratio is None else float(ratio))


@dataclass
class Results:
    """Everything a run produced."""

    records: list[Record] = field(default_factory=list)
    references: list[Record] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    profiles: dict[str, str] = field(default_factory=dict)
    calibrate_durations: dict[int, float] = field(default_factory=dict)

    def print(self) -> None:
        """Print the records, the references and the notes (a section run alone)."""
        for record in [*self.records, *self.references]:
            print(record)
        for note in self.notes:
            print(note)


@dataclass(frozen=True)
class Context:
    """What every section's ``run(context)`` gets: settings, results and output folders."""

    settings: Settings
    results: Results
    #: the run's output folder (``-o``); node logs go to ``logs/`` in it
    out: Path
    #: ``--quick``: shorter runs, one of each figure
    quick: bool
    #: ``--full``: the long samples too (50 + 50 Ctrl-C stops in the teardown section)
    full: bool = False

    @property
    def log_dir(self) -> Path:
        """Folder of the node processes' logs."""
        return self.out / "logs"


# --- machine -------------------------------------------------------------------------------

def load_note() -> str:
    """Return the load average now, for a section's notes (the machine is shared)."""
    one, five, fifteen = Path("/proc/loadavg").read_text().split()[:3]
    return (f"load average at the end of the section {one} {five} {fifteen} on "
            f"{os.cpu_count() or 0} cores")


def machine_info() -> dict[str, Any]:
    """Return cores, CPU model, memory, OS, Python and the load when the run started."""
    model = platform.processor() or "unknown"
    memory_mib = 0.0
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                memory_mib = int(line.split()[1]) / 1024
                break
    except OSError:
        pass
    return {
        "cores": os.cpu_count(),
        "cpu_model": model,
        "memory_mib": round(memory_mib),
        "os": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "load_average_at_start": [round(v, 2) for v in os.getloadavg()],
        "rmw": os.environ.get("RMW_IMPLEMENTATION", ""),
    }


# --- processes -----------------------------------------------------------------------------

def peak_rss_mib(pid: int) -> float | None:
    """Return VmHWM (peak resident set) of a live process [MiB], or ``None`` if it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


class Process:
    """A node process started by the benchmark, logging to a file, stopped by its PID."""

    def __init__(self, name: str, command: Sequence[str], log_dir: Path) -> None:
        self.name = name
        log_dir.mkdir(parents=True, exist_ok=True)
        self.log_path = log_dir / f"{name}.log"
        self._log: IO[bytes] = self.log_path.open("wb")
        self.popen = subprocess.Popen(list(command), stdout=self._log, stderr=subprocess.STDOUT,
                                      start_new_session=True)
        self.peak_mib = 0.0

    def sample_rss(self) -> None:
        """Keep the largest VmHWM seen (call it regularly and right before stopping)."""
        value = peak_rss_mib(self.popen.pid)
        if value is not None:
            self.peak_mib = max(self.peak_mib, value)

    def running(self) -> bool:
        """Whether the process has not exited yet."""
        return self.popen.poll() is None

    def stop(self, timeout: float = 10.0) -> int:
        """Sample its memory, send SIGINT, escalate to SIGKILL; return the exit code."""
        self.sample_rss()
        if self.popen.poll() is None:
            os.kill(self.popen.pid, signal.SIGINT)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                os.kill(self.popen.pid, signal.SIGKILL)
                self.popen.wait(timeout)
        self._log.close()
        return self.popen.returncode

    def output(self) -> str:
        """Everything the process printed."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")


@contextmanager
def processes(*started: Process) -> Iterator[tuple[Process, ...]]:
    """Stop every started process when the block ends, whatever happened."""
    try:
        yield started
    finally:
        for proc in started:
            proc.stop()


def helper_command(module: str, *args: str) -> list[str]:
    """Return the argv that runs the helper ``common.<module>`` as a process of its own.

    ``python -m common.<module>`` with bench/ first on the child's PYTHONPATH: the helper then
    imports its siblings as ``common.*``, as every benchmark does, from wherever it is started.
    """
    path = os.pathsep.join(p for p in (str(BENCH_DIR), os.environ.get("PYTHONPATH", "")) if p)
    return ["env", f"PYTHONPATH={path}", sys.executable, "-m", f"common.{module}", *args]


def launcher(package: str, name: str) -> str:
    """Return the installed ``lib/<package>/<name>`` launcher (what ``ros2 run`` starts)."""
    from es_bringup.bringup import executable

    return str(executable(package, name))


def wait_for_controllers(started: Sequence[Process], timeout: float) -> float:
    """Wait until the thermal and feedforward nodes are on the graph; return the wait [s].

    The plant is started only then, so that a slow node start-up (the thermal model of a
    large grid) is not counted in the lockstep figure and is not stepped past.
    """
    import rclpy

    from es_msgs_py import topics

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("bench_graph_probe", context=context)
    start = time.monotonic()
    try:
        while time.monotonic() - start < timeout:
            for proc in started:
                if not proc.running():
                    raise RuntimeError(f"{proc.name} exited: {proc.output()[-800:]}")
            if (node.count_subscribers(topics.TEMPERATURE_RAW) > 0
                    and node.count_subscribers(topics.SETPOINT) > 0
                    and node.count_publishers(topics.TEMPERATURE) > 0
                    and node.count_publishers(topics.COMMAND) > 0):
                return time.monotonic() - start
            time.sleep(0.1)
        raise RuntimeError(f"thermal/feedforward nodes not on the graph after {timeout:g} s")
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def run_until_exit(primary: Process, watched: Sequence[Process], timeout: float) -> None:
    """Sample the memory of ``watched`` until ``primary`` exits; raise after ``timeout``."""
    deadline = time.monotonic() + timeout
    while primary.running() and time.monotonic() < deadline:
        for proc in watched:
            proc.sample_rss()
        time.sleep(0.1)
    if primary.running():
        raise RuntimeError(f"{primary.name} did not finish within {timeout:g} s")
    for proc in watched:
        proc.sample_rss()


def plant_speedup(output: str) -> tuple[float, str]:
    """Return the plant node's sim/wall factor and its counts from its ``finished`` line.

    Raises:
        RuntimeError: the output has no ``finished`` summary.

    """
    match = re.search(r"finished: (\d+) steps, ([\d.e+-]+) s sim in ([\d.]+) s wall "
                      r"\(([\d.]+)x real time.*?\); (.*)", output)
    if match is None:
        raise RuntimeError("plant_node printed no 'finished' summary:\n" + output[-1500:])
    return float(match.group(4)), match.group(5).strip()


def top_of(profile: Path, count: int = 16) -> str:
    """Return the ``count`` functions with the most own time in a cProfile file."""
    if not profile.exists():
        return f"(no profile written to {profile})"
    text = io.StringIO()
    stats = pstats.Stats(str(profile), stream=text)
    stats.sort_stats("tottime").print_stats(count)
    return text.getvalue()
