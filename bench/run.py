"""Run the es_dm benchmark suite and write ``bench.md`` (tables) and ``bench.json`` (records).

Usage (from the repository root; ``scripts/bench`` bootstraps the venv and calls this)::

    .venv/bin/python bench/run.py [-o OUT] [--quick] [--only SECTION ...] [--no-profile]

Sections (``--only``): ``kernels`` (bench_kernels.py), ``convert`` (bench_convert.py),
``feedforward`` (the feedforward node over DDS against a plain rclpy relay, relay.py),
``lockstep`` (plant, thermal and feedforward processes in lockstep on ``dm_exposure``),
``recorder`` (the recorder's memory while it records a 32 x 32 lockstep run),
``calibrate`` (bench_calibrate.py), ``thermal`` (bench_thermal.py), ``calibration_loop``
(bench_calibration_loop.py: characterise, calibrate, closed loop per effect family; writes
``calibration_loop.md``/``.json``), ``import`` (bench_import.py: lab recordings into bags,
time and peak memory), ``scale`` (bench_scale.py: the feedforward node at 66 x 66 / 2 kHz and
128 x 128 / 1 kHz), ``lockstep_scale`` (bench_scale.py: the closed loop at 32 x 32 and
64 x 64), ``multihost`` (bench_multihost.py: 64 x 64 at 1 kHz across two network namespaces;
needs root), ``selfsensing`` (bench_selfsensing.py, offline cores). Peak memory of every
node process comes with the sections that start them. ``identify`` (the identification sweep
of identify.py on standgen bags, its own report in OUT/identify) is not in the default
selection: run it with ``--only identify``; nor is ``calibrate_stream``
(bench_calibrate_stream.py: streamed calibration of 64 x 64 and 128 x 128 bags of many GB).

Every figure is the median of repeated runs with their min and max (``summary.md``: the
compact table the README shows). ``bench.json`` holds
``{"date", "command", "machine", "settings", "records", "references", "notes", "failures"}``;
``records`` has one ``{"name", "n", "median", "min", "max", "unit", "ratio"}`` per figure with
the names of issue 9 (``ratio`` null where there is no floor or relay); ``references`` holds
the floors and the relay in the same format. A section that fails is reported in
``failures`` and in bench.md, the others still run; the exit code is then 1.

DDS runs use ROS_DOMAIN_ID from the environment (default 1 + pid % 101) and localhost
discovery only. Nothing here is asserted: targets are compared in the notes.
"""

from __future__ import annotations

import argparse
import datetime as dt
import io
import json
import os
import platform
import pstats
import re
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import IO, Any

from es_msgs_py.topics import process_domain_id

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(process_domain_id()))
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("PYTHONUNBUFFERED", "1")

import numpy as np

BENCH_DIR = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH_DIR))  # the sibling bench_*.py modules

from bench_calibrate_stream import section_calibrate_stream  # noqa: E402 - after the path
from bench_multihost import section_multihost  # noqa: E402 - after the path above
from bench_scale import section_lockstep_scale, section_scale  # noqa: E402

SECTIONS = ("kernels", "convert", "feedforward", "lockstep", "recorder", "calibrate", "thermal",
            "calibration_loop", "import", "scale", "lockstep_scale", "multihost", "selfsensing",
            "identify", "teardown", "feedforward_load", "calibrate_stream")
#: Sections run when ``--only`` is not given (the identification sweep has its own command).
DEFAULT_SECTIONS = tuple(name for name in SECTIONS if name not in ("identify", "calibrate_stream"))


#: Grid shapes of the DDS benchmark (N = 144, 1024, 4096).
DDS_SHAPES = ((12, 12), (32, 32), (64, 64))
#: Grids of the lockstep benchmark.
LOCKSTEP_SHAPES = ((12, 12), (32, 32))
#: Set points in flight during the rate measurement (far below the /dm QoS depth).
RATE_WINDOW = 4
#: Set-point rate [Hz] of the paced latency run (the issue's 1 kHz).
PACED_RATE = 1000.0
#: Grid and CPU hogs of the feedforward-under-load run (4096 doubles, two hogs: issue 17).
LOAD_SHAPE = (64, 64)
LOAD_CPU_HOGS = 2


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


# --- machine -------------------------------------------------------------------------------

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


def launcher(package: str, name: str) -> str:
    """Return the installed ``lib/<package>/<name>`` launcher (what ``ros2 run`` starts)."""
    from es_sim_plant.bringup import executable

    return str(executable(package, name))


# --- sections: in-process kernels ----------------------------------------------------------

def section_kernels(settings: Settings, results: Results) -> None:
    """Each mode's per-set-point cost and the laws+inverse kernel, against one np.sqrt."""
    from bench_kernels import bench_kernels

    runs = [bench_kernels(settings.kernel_sizes, repeats=1) for _ in range(settings.repeats)]
    keys = [(row.kernel, row.size) for row in runs[0]]
    for index, (kernel, size) in enumerate(keys):
        rows = [run[index] for run in runs]
        name = "kernel_" + kernel.replace("laws+", "laws_")
        ratio = float(np.median([row.ratio_to_sqrt for row in rows]))
        results.records.append(Record.of(name, size, [r.seconds_per_call for r in rows], "s",
                                          ratio))
    for size in settings.kernel_sizes:
        floor = [row.sqrt_seconds_per_call for run in runs for row in run if row.size == size]
        results.references.append(Record.of("floor_np_sqrt", size, floor, "s"))
    results.notes.append(
        "kernel_<mode>: Feedforward.command of that mode with the temperature laws already "
        "evaluated (the cost per set point); kernel_laws_inverse_hyperbolic: laws and "
        "hyperbolic inverse together; kernel_update_temperature: laws at a new temperature. "
        "ratio = time / one np.sqrt over the same N, measured alternately in the same run."
    )


def section_convert(settings: Settings, results: Results) -> None:
    """Numpy <-> Float64MultiArray for the kernel sizes, against a plain copy."""
    from bench_convert import bench_conversion

    runs = [bench_conversion(settings.kernel_sizes, repeats=5, number=500)
            for _ in range(settings.repeats)]
    for index, size in enumerate(settings.kernel_sizes):
        rows = [run[index] for run in runs]
        memcpy = [row.memcpy_us * 1e-6 for row in rows]
        floor = float(np.median(memcpy))
        to_msg = [row.to_msg_us * 1e-6 for row in rows]
        from_msg = [row.from_msg_us * 1e-6 for row in rows]
        results.records.append(Record.of("convert_to_msg", size, to_msg, "s",
                                          float(np.median(to_msg)) / floor))
        results.records.append(Record.of("convert_from_msg", size, from_msg, "s",
                                          float(np.median(from_msg)) / floor))
        results.references.append(Record.of("floor_copyto", size, memcpy, "s"))
    results.notes.append("convert_*: ratio = time / one np.copyto of the same array.")


def section_calibrate(settings: Settings, results: Results) -> None:
    """Calibration tool wall time on synthetic measured-data bags (1 x 1 and 32 x 32)."""
    from bench_calibrate import bench_calibrate

    for grid, duration, repeats in ((1, settings.calibrate_small_duration, settings.repeats),
                                    (32, settings.calibrate_large_duration, 1)):
        timings = [bench_calibrate(grid, grid, duration, settings.calibrate_rate)
                   for _ in range(repeats)]
        results.records.append(Record.of("calibrate_time", grid * grid,
                                          [t.calibrate_s for t in timings], "s"))
        results.calibrate_durations[grid * grid] = duration
        results.notes.append(
            f"calibrate_time n={grid * grid}: {grid} x {grid} actuators, {duration:g} s of data "
            f"at {settings.calibrate_rate:g} Hz, {repeats} run(s); generating the bag took "
            f"{np.median([t.generate_s for t in timings]):.1f} s (not included)."
        )
        if grid == 32 and settings.profile and np.median([t.calibrate_s for t in timings]) > 60:
            results.profiles["calibration of 32 x 32 x 30 s at 500 Hz"] = _profile_calibration(
                settings.calibrate_rate)


def section_calibration_loop(results: Results, out: Path) -> None:
    """Run the calibration loop per effect family; closed-loop error against no effect."""
    from bench_calibration_loop import loop_table, markdown, write_outputs

    with tempfile.TemporaryDirectory(prefix="bench_calibration_loop_") as tmp:
        loops = loop_table(Path(tmp))
    path = write_outputs(loops, out)
    results.notes.append(f"calibration_loop: table in {path.name}; " + markdown(loops)[0])


def _profile_calibration(rate: float) -> str:
    """Profile the calibration tool (in this process) on a 32 x 32 bag of 30 s."""
    import cProfile

    from bench_calibrate import write_measured_bag

    from es_feedforward.calibrate import run

    with tempfile.TemporaryDirectory(prefix="bench_calibrate_profile_") as tmp:
        bag = Path(tmp) / "bag"
        write_measured_bag(bag, 32, 32, 30.0, rate)
        profile = Path(tmp) / "calibrate.prof"
        profiler = cProfile.Profile()
        profiler.runcall(run, [str(bag), "-o", str(Path(tmp) / "out"), "-q"])
        profiler.dump_stats(profile)
        return _top_of(profile, 14)


def section_import(quick: bool, results: Results) -> None:
    """Import of lab recordings (issue 19): time and peak memory per format, one run each."""
    from bench_import import describe, run_cases

    for t in run_cases(quick):
        n = t.rows * t.cols
        results.records.append(Record.of(f"import_time_{t.fmt}_{t.samples}", n, [t.seconds], "s"))
        results.records.append(Record.of(f"import_mem_{t.fmt}_{t.samples}", n, [t.import_mib],
                                         "MiB"))
        results.notes.append(f"import: {describe(t)}")


def section_thermal(settings: Settings, results: Results) -> None:
    """Estimation accuracy of the thermal issue's goal run (degC rms), both estimators."""
    from bench_thermal import NODE_COST_GRIDS, node_cost, thermal_accuracy

    figures = thermal_accuracy()  # a seeded simulation: every repeat gives the same figures
    for name in ("thermal_rms_model", "thermal_rms_lowpass"):
        results.records.append(Record.of(name, 144, [figures[name]], "degC"))
    for size in NODE_COST_GRIDS:
        costs = [node_cost(size, size) for _ in range(settings.repeats)]
        results.records.append(Record.of("thermal_build_time", size * size,
                                         [c["build_s"] for c in costs], "s"))
        results.records.append(Record.of("thermal_update_time", size * size,
                                         [c["update_ms_median"] for c in costs], "ms"))
    results.notes.append(
        "thermal_rms_*: bench_thermal.thermal_accuracy() defaults (dm_exposure 12 x 12, one "
        "sensor per 2 x 2 actuators, 0.01 degC noise, model parameters 20 % off); one run "
        f"(deterministic); max error model {figures['thermal_max_model']:.3g} degC, lowpass "
        f"{figures['thermal_max_lowpass']:.3g} degC; update "
        f"{figures['thermal_update_ms_model']:.2g} ms (model), "
        f"{figures['thermal_update_ms_lowpass']:.2g} ms (lowpass). thermal_build_time / "
        "thermal_update_time: bench_thermal.node_cost(), the model estimator as the thermal "
        "node builds it for the lockstep runs (dm_exposure, one sensor per actuator), one "
        "build and the median of 200 updates per repeat, in process, no DDS."
    )


def section_selfsensing(results: Results) -> None:
    """Issue 20: temperature error and variation with 4 NTCs, + self-sensing, NTC each."""
    from bench_selfsensing import goal_checks, selfsensing_figures

    from es_sim_plant.selfsensing_study import CASES

    figures = selfsensing_figures()  # seeded: every repeat gives the same figures
    for case in CASES:
        for kind in ("rms", "worst"):
            name = f"selfsensing_{kind}_{case}"
            results.records.append(Record.of(name, 144, [figures[name]], "degC"))
        name = f"selfsensing_variation_{case}"
        results.records.append(Record.of(name, 144, [figures[name] * 1e9], "nm"))
    for name in ("selfsensing_gain", "selfsensing_variation_ratio"):
        results.records.append(Record.of(name, 144, [figures[name]], "x"))
    results.notes.append(
        "selfsensing_*: bench_selfsensing.selfsensing_figures() (offline cores; laws calibrated "
        "from the characterisation scenario with the sweeps on; dm_exposure 12 x 12 with (a) 4 "
        "NTCs, (b) 4 NTCs + self-sensing, (c) an NTC per actuator; feedforward on the true "
        f"laws); one run (deterministic), {figures['selfsensing_calibration_s']:.2g} s "
        f"calibration, {figures['selfsensing_study_s']:.2g} s for the cases. Goals: "
        + "; ".join(goal_checks(figures))
        + "."
    )


def section_identify(quick: bool, results: Results, out: Path) -> None:
    """Run the identification sweep (identify.py): right effect sets, clean FP rate, RMS."""
    import identify

    jobs = min(2, os.cpu_count() or 1)
    start = time.monotonic()
    outcomes = identify.run_sweep(identify.build_cases(quick=quick), jobs=jobs,
                                  keep=out / "cases")
    wall = time.monotonic() - start
    summary = identify.write_results(out, outcomes, {
        "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "command": f"bench/run.py --only identify{' --quick' if quick else ''}",
        "quick": quick, "jobs": jobs, "seed": 0, "cores": os.cpu_count(), "wall_s": wall})
    n = summary["cases"]
    for name, key in (("identify_single_right", "single_right"),
                      ("identify_pair_right", "pair_right"),
                      ("identify_clean_false_positive", "clean_false_positive_rate"),
                      ("identify_right_within_1p2_noise", "right_within_1p2_true_noise")):
        if summary[key] is not None:
            results.records.append(Record.of(name, n, [summary[key]], "fraction"))
    results.records.append(Record.of("identify_wall_time", n, [wall], "s"))
    results.notes.append(f"identify_*: {n} standgen cases ({'quick' if quick else 'full'}), "
                         f"{jobs} jobs; goals: {'; '.join(identify.goal_lines(summary))}; "
                         f"tables in {out / 'identify.md'}.")


# --- sections: DDS -------------------------------------------------------------------------

class DdsClient:
    """In-process rclpy node that feeds set points and times the commands coming back."""

    def __init__(self, shape: tuple[int, int]) -> None:
        import rclpy
        from std_msgs.msg import Float64MultiArray

        from es_msgs_py.arrays import grid_to_msg
        from es_msgs_py.topics import COMMAND, SETPOINT, TEMPERATURE, qos_for
        from es_physics.laws import z_sat
        from es_physics.params import ActuatorParams

        self.shape = shape
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("bench_client", context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.setpoint_pub = self.node.create_publisher(Float64MultiArray, SETPOINT,
                                                       qos_for(SETPOINT))
        self.temperature_pub = self.node.create_publisher(Float64MultiArray, TEMPERATURE,
                                                          qos_for(TEMPERATURE))
        self.sent = 0
        self.received = 0
        self.received_at: list[float] = []
        self.last_command: Float64MultiArray | None = None
        self.command_sub = self.node.create_subscription(Float64MultiArray, COMMAND,
                                                         self._on_command, qos_for(COMMAND))
        # Set points from 10 % to 60 % of z_sat at 46 degC, changing from message to message.
        reach = float(z_sat(46.0, ActuatorParams()))
        phases = np.random.default_rng(0).uniform(0, 2 * np.pi, shape)
        self.messages = [
            grid_to_msg(reach * (0.35 + 0.25 * np.sin(phases + k * 0.4))) for k in range(16)
        ]
        self.temperature = grid_to_msg(np.full(shape, 46.0))

    def _on_command(self, msg: Any) -> None:
        self.received += 1
        self.received_at.append(time.perf_counter())
        self.last_command = msg

    def publish(self, msg: Any) -> None:
        """Publish one set point (counted in ``sent``)."""
        self.setpoint_pub.publish(msg)
        self.sent += 1

    def wait_for_peer(self, setpoint_readers: int = 1, estimates: bool = False,
                      timeout: float = 60.0) -> None:
        """Wait until the client's endpoints matched their peers.

        Peers: ``setpoint_readers`` subscriptions of its set points (the node, a recorder),
        the node's estimate subscription when ``estimates``, the node's command publisher.

        Raises:
            RuntimeError: not matched within ``timeout`` (names what is missing).

        """
        wanted = [("set-point subscriptions", self.setpoint_pub.get_subscription_count,
                   setpoint_readers),
                  ("command publishers", self.command_sub.get_publisher_count, 1)]
        if estimates:
            wanted.append(("estimate subscriptions",
                           self.temperature_pub.get_subscription_count, 1))
        deadline = time.monotonic() + timeout
        while (missing := [f"{what} {count()} of {n}" for what, count, n in wanted
                           if count() < n]):
            if time.monotonic() > deadline:
                raise RuntimeError(f"not matched within {timeout:g} s: {', '.join(missing)}")
            self.executor.spin_once(timeout_sec=0.05)

    def use_temperature(self, timeout: float = 60.0) -> None:
        """Send the estimate, then set points until a command shows it was taken (not 0 V).

        Raises:
            RuntimeError: every command within ``timeout`` was 0 V (the estimate never came).

        """
        from es_msgs_py.arrays import msg_to_grid

        self.temperature_pub.publish(self.temperature)
        deadline = time.monotonic() + timeout
        while True:
            self.latencies(1)
            assert self.last_command is not None
            if np.any(msg_to_grid(self.last_command) > 0.0):
                return
            if time.monotonic() > deadline:
                raise RuntimeError("feedforward holds (all 0 V): temperature not taken within "
                                   f"{timeout:g} s")

    def _wait_received(self, count: int, timeout: float) -> int:
        """Spin until ``count`` commands arrived or ``timeout`` s; return how many are missing."""
        deadline = time.monotonic() + timeout
        while self.received < count and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)
        return max(count - self.received, 0)

    def latencies(self, samples: int) -> np.ndarray:
        """Ping-pong: send one set point, wait for its command; return latencies [s]."""
        out = np.empty(samples)
        for i in range(samples):
            target = self.received + 1
            start = time.perf_counter()
            self.publish(self.messages[i % len(self.messages)])
            if self._wait_received(target, 10.0):
                raise RuntimeError(f"no command came back within 10 s (set point {self.sent})")
            out[i] = self.received_at[-1] - start
        return out

    def paced(self, rate_hz: float, seconds: float) -> tuple[np.ndarray | None, float, int]:
        """Send set points at ``rate_hz`` for ``seconds``; return (latencies, rate, lost).

        Latencies in s, the rate the client achieved in Hz, lost: commands that did not come
        back within 10 s. Commands come back in order (reliable QoS, one per set point), so
        the k-th command answers the k-th set point; when some are lost that pairing is gone
        and the latencies are ``None``.
        """
        period = 1.0 / rate_hz
        count = round(seconds * rate_hz)
        sent_at = np.empty(count)
        first = self.received
        first_index = len(self.received_at)
        start = time.perf_counter()
        for k in range(count):
            due = start + k * period
            while (left := due - time.perf_counter()) > 0.0:
                self.executor.spin_once(timeout_sec=left)
            sent_at[k] = time.perf_counter()
            self.publish(self.messages[k % len(self.messages)])
        sent_rate = (count - 1) / (sent_at[-1] - sent_at[0])
        lost = self._wait_received(first + count, 10.0)
        if lost:
            return None, sent_rate, lost
        received_at = np.asarray(self.received_at[first_index:first_index + count])
        return received_at - sent_at, sent_rate, 0

    def rate(self, seconds: float) -> tuple[float, int]:
        """Keep RATE_WINDOW set points in flight for ``seconds``; return (rate, lost).

        Rate: commands per second; lost: commands that did not come back within 10 s.
        """
        sent = 0
        first = self.received
        start = time.perf_counter()
        last_progress = time.monotonic()
        seen = self.received
        while time.perf_counter() - start < seconds:
            while sent - (self.received - first) < RATE_WINDOW:
                self.publish(self.messages[sent % len(self.messages)])
                sent += 1
            self.executor.spin_once(timeout_sec=0.05)
            if self.received != seen:
                seen, last_progress = self.received, time.monotonic()
            elif time.monotonic() - last_progress > 5.0:
                break  # commands stopped coming back: the drain below counts the lost ones
        elapsed = time.perf_counter() - start
        done = self.received - first
        return done / elapsed, self._wait_received(first + sent, 10.0)

    def close(self) -> None:
        """Destroy the node and shut its context down."""
        self.node.destroy_node()
        import rclpy

        rclpy.shutdown(context=self.context)


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
        command = [sys.executable, str(BENCH_DIR / "relay.py"), "--ros-args", "-r",
                   "__node:=relay", "-p", f"executor:={executor}"]
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


def section_feedforward(settings: Settings, results: Results, log_dir: Path) -> None:
    """Feedforward node vs a plain relay over DDS: rate, p50/p99 latency, peak memory."""
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


@dataclass
class LoadRun:
    """One feedforward run with a recorder beside it, idle or beside CPU hogs."""

    p99_ms: float
    rate_hz: float
    paced_p99_ms: float | None
    paced_rate_hz: float
    counts: dict[str, int]

    @property
    def lost(self) -> int:
        """Set points without a command back, plus messages the recorder did not write."""
        c = self.counts
        return ((c["setpoints_sent"] - c["commands_received"])
                + (c["setpoints_sent"] - c["setpoints_in_bag"])
                + (c["commands_published"] - c["commands_in_bag"]))


def _wait_recorder_has(client: DdsClient, recorder: Process, timeout: float = 60.0) -> None:
    """Wait until the recorder's /diagnostics report every command the client received.

    Then it matched the node's command publisher before the first command went out: what it
    misses later is a loss, not start-up.

    Raises:
        RuntimeError: the recorder did not report them within ``timeout``.

    """
    from diagnostic_msgs.msg import DiagnosticArray

    from es_msgs_py.topics import COMMAND, DIAGNOSTICS, qos_for

    reported = -1

    def on_report(msg: Any) -> None:
        nonlocal reported
        for status in msg.status:
            for pair in status.values:
                if pair.key == f"{COMMAND} received" and pair.value.isdigit():
                    reported = int(pair.value)

    sub = client.node.create_subscription(DiagnosticArray, DIAGNOSTICS, on_report,
                                          qos_for(DIAGNOSTICS))
    deadline = time.monotonic() + timeout
    try:
        while reported < client.received:
            if time.monotonic() > deadline or not recorder.running():
                raise RuntimeError(f"recorder reports {reported} of {client.received} commands "
                                   f"after {timeout:g} s: it matched the node late")
            client.executor.spin_once(timeout_sec=0.1)
    finally:
        client.node.destroy_subscription(sub)


def _load_run(loaded: bool, settings: Settings, log_dir: Path, paced_s: float) -> LoadRun:
    """Feedforward at LOAD_SHAPE with a recorder on set points and commands, hogs or not."""
    from load import hogs

    from es_msgs_py.bag import read_bag
    from es_msgs_py.topics import COMMAND, SETPOINT
    from es_sim_plant.invariants import published_counts_from_log, recorder_counts_from_log

    rows, cols = LOAD_SHAPE
    label = "loaded" if loaded else "idle"
    with tempfile.TemporaryDirectory(prefix="bench_load_") as tmp, \
            hogs(cpu=LOAD_CPU_HOGS if loaded else 0):
        bag = Path(tmp) / "bag"
        recorder = Process(f"record_{label}", [launcher("es_msgs_py", "record"), "-o", str(bag),
                                               SETPOINT, COMMAND], log_dir)
        node = Process(f"feedforward_{label}_{rows}x{cols}", [
            launcher("es_feedforward", "feedforward_node"), "--ros-args", "-p", f"rows:={rows}",
            "-p", f"cols:={cols}", "-p", "temperature_timeout:=0.0"], log_dir)
        client = DdsClient(LOAD_SHAPE)
        try:
            with processes(node, recorder):  # the node stops first, the recorder last
                client.wait_for_peer(setpoint_readers=2, estimates=True)
                client.use_temperature()
                _wait_recorder_has(client, recorder)
                lat = client.latencies(settings.dds_latency_samples)
                rate, _ = client.rate(settings.dds_rate_seconds)
                paced, paced_rate, _ = client.paced(PACED_RATE, paced_s)
                client._wait_received(client.sent, 10.0)  # every late command, before the stop
                node.stop()
                recorder.stop()
            published = published_counts_from_log(node.output().splitlines(), (COMMAND,))
            recorded = recorder_counts_from_log(recorder.output().splitlines())
            in_bag = read_bag(bag, [SETPOINT, COMMAND])
            counts = {
                "setpoints_sent": client.sent,
                "commands_published": published.get(COMMAND, -1),
                "commands_received": client.received,
                "setpoints_recorded": recorded.get(SETPOINT, (-1, -1, -1))[1],
                "commands_recorded": recorded.get(COMMAND, (-1, -1, -1))[1],
                "setpoints_in_bag": len(in_bag[SETPOINT]) if SETPOINT in in_bag else 0,
                "commands_in_bag": len(in_bag[COMMAND]) if COMMAND in in_bag else 0,
            }
        finally:
            client.close()
    return LoadRun(float(np.percentile(lat, 99)) * 1e3, rate,
                   None if paced is None else float(np.percentile(paced, 99)) * 1e3,
                   paced_rate, counts)


def section_feedforward_load(settings: Settings, results: Results, log_dir: Path) -> None:
    """Feedforward at 4096 with a recorder, idle and beside two CPU hogs: rate, p99, loss."""
    paced_s = 10.0 if settings.repeats > 1 else 3.0
    runs: dict[bool, list[LoadRun]] = {False: [], True: []}
    for _ in range(settings.repeats):
        for loaded in (False, True):  # in turns: a change of the machine's load hits both
            runs[loaded].append(_load_run(loaded, settings, log_dir, paced_s))
    n = LOAD_SHAPE[0] * LOAD_SHAPE[1]
    for loaded, label in ((False, "idle"), (True, "loaded")):
        done = runs[loaded]
        results.records.append(Record.of(f"load_{label}_rate", n, [r.rate_hz for r in done],
                                         "Hz"))
        results.records.append(Record.of(f"load_{label}_latency_p99", n,
                                         [r.p99_ms for r in done], "ms"))
        paced = [r.paced_p99_ms for r in done if r.paced_p99_ms is not None]
        if paced:
            results.records.append(Record.of(f"load_{label}_paced_latency_p99", n, paced, "ms"))
        results.records.append(Record.of(f"load_{label}_lost", n, [r.lost for r in done],
                                         "messages"))
        for i, r in enumerate(done):
            counts = ", ".join(f"{k} {v}" for k, v in r.counts.items())
            results.notes.append(f"load_{label} run {i + 1}: {counts}; client sent "
                                 f"{r.paced_rate_hz:.0f} Hz in the paced run")
    results.notes.append(
        f"load_*: the feedforward node at {LOAD_SHAPE[0]} x {LOAD_SHAPE[1]} with a recorder on "
        f"/dm/setpoint and /dm/command, idle and beside {LOAD_CPU_HOGS} CPU hogs "
        "(bench/load.py), in turns; latency_p99 one set point at a time, rate with "
        f"{RATE_WINDOW} in flight, paced_latency_p99 while set points stream at "
        f"{PACED_RATE:g} Hz for {paced_s:g} s; lost: set points without a command back plus "
        "set points and commands missing from the bag (published == received == recorded "
        "when 0); a paced p99 is left out of a run that lost commands (no pairing)."
    )


def _profile_feedforward(results: Results, log_dir: Path) -> None:
    """CProfile of the feedforward node process while it serves set points at 64 x 64."""
    profile = log_dir / "feedforward_64x64.prof"
    quick = Settings.create(quick=True, profile=False)
    _measure_node("feedforward", DDS_SHAPES[-1], quick, log_dir, profile_to=profile)
    results.profiles["feedforward node at 64 x 64, serving set points"] = _top_of(profile)


def _top_of(profile: Path, count: int = 16) -> str:
    """Return the ``count`` functions with the most own time in a cProfile file."""
    if not profile.exists():
        return f"(no profile written to {profile})"
    text = io.StringIO()
    stats = pstats.Stats(str(profile), stream=text)
    stats.sort_stats("tottime").print_stats(count)
    return text.getvalue()


def _plant_speedup(output: str) -> tuple[float, str]:
    match = re.search(r"finished: (\d+) steps, ([\d.e+-]+) s sim in ([\d.]+) s wall "
                      r"\(([\d.]+)x real time.*?\); (.*)", output)
    if match is None:
        raise RuntimeError("plant_node printed no 'finished' summary:\n" + output[-1500:])
    return float(match.group(4)), match.group(5).strip()


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


def _run_until_exit(primary: Process, watched: Sequence[Process], timeout: float) -> None:
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


def section_lockstep(settings: Settings, results: Results, log_dir: Path) -> None:
    """Plant, thermal and feedforward processes in lockstep: sim/wall factor, peak memory."""
    from es_sim_plant.bringup import GraphConfig, node_specs

    for rows, cols in LOCKSTEP_SHAPES:
        n = rows * cols
        speedups: list[float] = []
        peaks: dict[str, list[float]] = {}
        # The thermal node of a 32 x 32 grid takes minutes to start: one run of large grids.
        repeats = settings.repeats if n <= 144 else 1
        for repeat in range(repeats):
            config = GraphConfig(
                scenario="dm_exposure",
                plant={"rows": rows, "cols": cols, "duration": settings.lockstep_duration},
            )
            before, plant_spec = node_specs(config)
            tag = f"{rows}x{cols}_{repeat}"
            started = [Process(f"{s.name}_{tag}", s.command, log_dir) for s in before]
            with processes(*started):
                ready_s = wait_for_controllers(started, 300.0)
                plant = Process(f"{plant_spec.name}_{tag}", plant_spec.command, log_dir)
                with processes(plant):
                    _run_until_exit(plant, [*started, plant],
                                    120.0 + 20.0 * settings.lockstep_duration)
            speedup, counts = _plant_speedup(plant.output())
            speedups.append(speedup)
            for spec, proc in zip([*before, plant_spec], [*started, plant], strict=True):
                peaks.setdefault(spec.name, []).append(proc.peak_mib)
            results.notes.append(f"lockstep {rows} x {cols} run {repeat + 1}: {speedup:.2f}x "
                                 f"real time; plant counts: {counts}; thermal and feedforward "
                                 f"ready {ready_s:.1f} s after their start")
        results.records.append(Record.of("lockstep_speedup", n, speedups, "sim/wall"))
        for name, values in peaks.items():
            if name != "feedforward":  # the DDS section reports the feedforward's memory
                results.records.append(Record.of(f"peak_rss_{name}", n, values, "MiB"))
    if settings.profile:
        _profile_lockstep(settings, results, log_dir)
    results.notes.append(
        f"lockstep_speedup: dm_exposure at 100 Hz control / 10 Hz sensors, "
        f"{settings.lockstep_duration:g} s sim, plant + thermal (model estimator) + "
        "feedforward (inverse_hyperbolic) as separate processes, the plant's own sim/wall "
        "figure (from its first step to its last)."
    )


def _profile_lockstep(settings: Settings, results: Results, log_dir: Path) -> None:
    """One 12 x 12 lockstep run with the plant and the feedforward node under cProfile."""
    from es_sim_plant.bringup import GraphConfig, node_specs

    config = GraphConfig(scenario="dm_exposure",
                         plant={"rows": 12, "cols": 12, "duration": settings.lockstep_duration})
    before, plant_spec = node_specs(config)
    modules = {"plant": "es_sim_plant.plant_node", "feedforward": "es_feedforward.feedforward_node",
               "thermal": "es_thermal.thermal_node"}

    def profiled(name: str, command: Sequence[str]) -> list[str]:
        return [sys.executable, "-m", "cProfile", "-o", str(log_dir / f"lockstep_{name}.prof"),
                "-m", modules[name], *command[1:]]

    started = [Process(f"{s.name}_profiled", profiled(s.name, s.command), log_dir)
               for s in before]
    with processes(*started):
        wait_for_controllers(started, 300.0)
        plant = Process("plant_profiled", profiled("plant", plant_spec.command), log_dir)
        with processes(plant):
            _run_until_exit(plant, [plant], 120.0 + 20.0 * settings.lockstep_duration)
    for name in ("plant", "feedforward", "thermal"):
        results.profiles[f"{name} node in a 12 x 12 lockstep run"] = _top_of(
            log_dir / f"lockstep_{name}.prof", 12)


def section_recorder(results: Results, log_dir: Path) -> None:
    """Peak memory of the recorder while it records a 32 x 32 lockstep run (all /dm topics)."""
    from es_sim_plant.bringup import GraphConfig, node_specs

    with tempfile.TemporaryDirectory(prefix="bench_record_") as tmp:
        config = GraphConfig(scenario="dm_exposure", bag=Path(tmp) / "bag",
                             plant={"rows": 32, "cols": 32, "duration": 10.0},
                             thermal={"estimator": "lowpass"})
        before, plant_spec = node_specs(config)
        started = [Process(f"{s.name}_recorded", s.command, log_dir) for s in before]
        with processes(*started):
            wait_for_controllers(started, 300.0)
            plant = Process("plant_recorded", plant_spec.command, log_dir)
            with processes(plant):
                _run_until_exit(plant, started, 300.0)
        recorder = started[0]
        results.records.append(Record.of("peak_rss_record", 1024, [recorder.peak_mib], "MiB"))
        speedup, _ = _plant_speedup(plant.output())
        results.notes.append(f"peak_rss_record: recorder on every /dm topic and /diagnostics "
                             f"of a 32 x 32 lockstep run of 10 s sim ({speedup:.2f}x real time "
                             "with the recorder; thermal node on the lowpass estimator, which "
                             "starts in seconds).")


# --- report --------------------------------------------------------------------------------

TARGETS = (
    ("kernel_inverse_hyperbolic", 4096, "ratio", "<=", 10.0, "kernels <= 10x np.sqrt at 4096"),
    ("feedforward_rate", 4096, "median", ">=", 1000.0, "feedforward >= 1 kHz at 4096"),
    ("feedforward_latency_p99", 4096, "median", "<=", 2.0, "p99 <= 2 ms at 4096"),
    ("feedforward_paced_latency_p99", 4096, "median", "<=", 2.0,
     "p99 <= 2 ms at 4096 while set points stream at 1 kHz"),
    ("feedforward_rate", 4096, "ratio", ">=", 0.9, "feedforward >= 0.9x the relay at 4096"),
    ("lockstep_speedup", 144, "median", ">=", 5.0, "lockstep >= 5x real time at 12 x 12"),
    ("calibrate_time", 1024, "median", "<=", 60.0, "calibration 32 x 32 x 5 min <= 60 s"),
)


def section_teardown(settings: Settings, results: Results) -> None:
    """Ctrl-C stops under ros2 launch and the bring-up (bench_teardown.py): crashes, times."""
    from bench_teardown import ros2_executable, teardown_stops

    stops = 5 if settings.repeats == 1 else 50
    kinds = ["launch", "bringup"] if ros2_executable() else ["bringup"]
    if "launch" not in kinds:
        results.failures.append("teardown: no ros2 for the launch stops (scripts/ros2cli-env)")
    for kind in kinds:
        outcome = teardown_stops(kind, stops)
        results.records.append(
            Record.of(f"teardown_crashes_{kind}", outcome.stops, [outcome.crashes], "crashes"))
        if outcome.stop_seconds:
            results.records.append(Record.of(f"teardown_stop_time_{kind}", outcome.stops,
                                             outcome.stop_seconds, "s"))
        results.notes += [f"teardown {kind} {note}" for note in outcome.crash_notes]
    results.notes.append(
        f"teardown: {stops} Ctrl-C stops (SIGINT to the ros2 launch / bringup PID) of a "
        "dm_exposure 12 x 12 lockstep graph with recorder, each 0.2-2 s after the feedforward "
        "was ready; a crash = a node died or printed a native stack, an unclean exit, a stop "
        "over 90 s or an unclosed bag; stop time = SIGINT to exit (median, min-max)."
    )


def check_targets(results: Results) -> list[str]:
    """Return one line per issue-9 target: met or missed, with the measured figure."""
    lines = []
    by_key = {(r.name, r.n): r for r in results.records}
    for name, n, attr, op, bound, label in TARGETS:
        if name.startswith("kernel_"):
            kernels = [r for r in results.records if r.name.startswith("kernel_") and r.n == n]
            if not kernels:
                lines.append(f"not measured: {label}")
            for kernel in kernels:
                ok = (kernel.ratio or 0.0) <= bound
                lines.append(f"{'met' if ok else 'MISSED'}: {label}: {kernel.name} "
                             f"{kernel.ratio or 0.0:.1f}x")
            continue
        record = by_key.get((name, n))
        if record is None:
            lines.append(f"not measured: {label}")
            continue
        if name == "calibrate_time" and results.calibrate_durations.get(n) != 300.0:
            seconds = results.calibrate_durations.get(n, 0.0)
            lines.append(f"not measured at 5 min: {label} (with {seconds:g} s of data: "
                         f"{record.median:.3g} s)")
            continue
        value = getattr(record, attr)
        ok = value <= bound if op == "<=" else value >= bound
        lines.append(f"{'met' if ok else 'MISSED'}: {label} (measured {value:.3g})")
    return lines


def _fmt(value: float | None) -> str:
    if value is None:
        return "-"
    return f"{value:.3g}"


def _table(records: Sequence[Record]) -> list[str]:
    lines = ["| name | n | median | min | max | unit | ratio |",
             "|---|---:|---:|---:|---:|---|---:|"]
    lines += [f"| {r.name} | {r.n} | {_fmt(r.median)} | {_fmt(r.min)} | {_fmt(r.max)} | "
              f"{r.unit} | {_fmt(r.ratio)} |" for r in records]
    return lines


def write_report(out: Path, results: Results, machine: dict[str, Any], settings: Settings,
                 *, date: str, command: str) -> None:
    """Write bench.json and bench.md into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    document = {
        "date": date, "command": command, "machine": machine, "settings": asdict(settings),
        "records": [asdict(r) for r in results.records],
        "references": [asdict(r) for r in results.references],
        "notes": results.notes, "failures": results.failures,
    }
    (out / "bench.json").write_text(json.dumps(document, indent=1) + "\n")
    cores, model = machine["cores"], machine["cpu_model"]
    md = [
        "# es_dm benchmarks", "",
        f"{date}, {cores} cores, {model}, {machine['memory_mib']} MiB, {machine['os']}, "
        f"Python {machine['python']}, {machine['rmw']}; load average at start "
        f"{machine['load_average_at_start']}. Command: `{command}`. Median of "
        f"{settings.repeats} run(s) with min and max.", "",
        *_table(results.records), "",
        "## Targets (issue 9)", "", *[f"- {line}" for line in check_targets(results)], "",
        "## Floors and relay (same run)", "", *_table(results.references), "",
        "## Notes", "", *[f"- {note}" for note in results.notes], "",
    ]
    if results.failures:
        md += ["## Failed sections", "", *[f"- {f}" for f in results.failures], ""]
    for title, text in results.profiles.items():
        md += [f"## Profile: {title} (cProfile, by own time)", "", "```", text.strip(), "```",
               ""]
    (out / "bench.md").write_text("\n".join(md))


#: Figures of the README's compact table: (name prefix, sizes; empty = every size).
SUMMARY_ROWS: tuple[tuple[str, tuple[int, ...]], ...] = (
    ("kernel_", (4096,)),
    ("convert_", (4096,)),
    ("feedforward_", ()),
    ("lockstep_speedup", ()),
    ("calibrate_time", ()),
    ("thermal_rms_", ()),
    ("selfsensing_", ()),
    ("thermal_build_time", ()),
    ("thermal_update_time", ()),
    ("peak_rss_", ()),
    ("identify_", ()),
)


def write_summary(out: Path, results: Results, machine: dict[str, Any], date: str) -> None:
    """Write summary.md: the compact table the README shows (full tables in bench.md)."""
    lines = [
        f"Measured {date} on {machine['cores']} cores, {machine['cpu_model']} (load average "
        f"{machine['load_average_at_start'][0]} at the start: a shared machine); median "
        "(min-max) of repeated runs.", "",
        "| figure | n | median (min-max) | unit | ratio |", "|---|---:|---|---|---:|",
    ]
    for prefix, sizes in SUMMARY_ROWS:
        for r in results.records:
            if r.name.startswith(prefix) and (not sizes or r.n in sizes):
                scale, unit = (1e6, "us") if r.unit == "s" and r.median < 0.01 else (1.0, r.unit)
                spread = (f"{_fmt(r.median * scale)} ({_fmt(r.min * scale)}-"
                          f"{_fmt(r.max * scale)})")
                lines.append(f"| {r.name} | {r.n} | {spread} | {unit} | {_fmt(r.ratio)} |")
    lines += ["", "Targets (issue 9):", "", *[f"- {t}" for t in check_targets(results)], ""]
    (out / "summary.md").write_text("\n".join(lines))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the selected sections and write the report; return 1 if a section failed."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%d-%H%M%S")
    parser.add_argument("-o", "--output", type=Path, default=Path(f"out/bench-{stamp}"))
    parser.add_argument("--quick", action="store_true",
                        help="one run of each figure, shorter runs (about 1.5 minutes)")
    parser.add_argument("--only", nargs="+", choices=SECTIONS, default=list(DEFAULT_SECTIONS))
    parser.add_argument("--no-profile", action="store_true",
                        help="skip the cProfile runs of the nodes and the calibration")
    parser.add_argument("--calibrate-seconds", type=float, default=None,
                        help="seconds of data of the 32 x 32 calibration case (300 = issue 9)")
    args = parser.parse_args(argv)
    settings = Settings.create(args.quick, profile=not args.no_profile,
                               calibrate_large=args.calibrate_seconds)
    machine = machine_info()
    date = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    command = " ".join(["bench/run.py", *(argv if argv is not None else sys.argv[1:])])
    log_dir = args.output / "logs"
    results = Results()
    sections: dict[str, Callable[[], None]] = {
        "kernels": lambda: section_kernels(settings, results),
        "convert": lambda: section_convert(settings, results),
        "feedforward": lambda: section_feedforward(settings, results, log_dir),
        "feedforward_load": lambda: section_feedforward_load(settings, results, log_dir),
        "lockstep": lambda: section_lockstep(settings, results, log_dir),
        "recorder": lambda: section_recorder(results, log_dir),
        "calibrate": lambda: section_calibrate(settings, results),
        "calibrate_stream": lambda: section_calibrate_stream(settings, results),
        "thermal": lambda: section_thermal(settings, results),
        "calibration_loop": lambda: section_calibration_loop(results, args.output),
        "import": lambda: section_import(args.quick, results),
        "scale": lambda: section_scale(settings, results, log_dir),
        "lockstep_scale": lambda: section_lockstep_scale(settings, results, log_dir),
        "multihost": lambda: section_multihost(settings, results, log_dir),
        "selfsensing": lambda: section_selfsensing(results),
        "identify": lambda: section_identify(args.quick, results, args.output / "identify"),
        "teardown": lambda: section_teardown(settings, results),
    }
    for name in args.only:
        start = time.monotonic()
        print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        try:
            sections[name]()
        except Exception as err:
            results.failures.append(f"{name}: {type(err).__name__}: {err}".splitlines()[0])
            traceback.print_exc()
        print(f"[bench] {name} done in {time.monotonic() - start:.0f} s", file=sys.stderr,
              flush=True)
        write_report(args.output, results, machine, settings, date=date, command=command)
        write_summary(args.output, results, machine, date)
    print(f"[bench] wrote {args.output / 'bench.md'} and {args.output / 'bench.json'}",
          file=sys.stderr)
    return 1 if results.failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
