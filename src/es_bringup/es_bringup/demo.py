"""``scripts/demo`` / ``ros2 run es_bringup demo``: the main job, end to end over ROS 2.

The product's story, in order, every step a separate process graph run by the bring-up
(:mod:`es_bringup.bringup`) and recorded into a bag:

1. characterisation: the simulator as a test stand (no feedforward; a signal-generator
   voltage program, a slow temperature ramp, interferometer noise), recorded like measured
   data, once for the single thesis actuator and once for the 12 x 12 mirror;
2. calibration: ``es_feedforward calibrate`` on each bag, told nothing about the simulator;
   it writes the parameters YAML the feedforward node loads;
3. the scenarios ``thesis_ac``, ``thesis_dc_ac`` and ``dm_exposure``, each with
   ``uncompensated`` and every compensating mode, using the calibrated parameters;
4. one calibration loop end to end: a test-stand bag with an effect the model lacks, the
   effect found, the error before and after, and the closed-loop tracking with the
   parameters before and after the effect was added; then self-sensing
   (:mod:`es_bringup.selfsensing_demo`): a test stand with the resonance sweeps,
   ``calibrate_resonance``, and ``dm_exposure`` with 4 NTCs, 4 NTCs + self-sensing and an
   NTC per actuator;
5. the report (Markdown + PNG + summary.json) in the output folder named at the end.

Runs go in parallel (``--jobs``) in one ROS domain, each graph below its own namespace
(``/run0``, ``/run1``, ...; the bags keep the contract's topic names) so they never see each
other.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import yaml

from es_bringup import selfsensing_demo
from es_bringup.analysis import RunAnalysis, analyse_run
from es_bringup.bringup import Bringup, GraphConfig, ParamValue, executable
from es_bringup.report import ReportInputs, RunResult, write_report
from es_msgs_py.topics import RESONANCE, process_domain_id
from es_sim_plant.plant import sensor_every
from es_sim_plant.scenario import Scenario, load_scenario, resolve_scenario

#: Closed-loop scenarios of the main job.
SCENARIOS: tuple[str, ...] = ("thesis_ac", "thesis_dc_ac", "dm_exposure")
#: Feedforward modes: the baseline first, then every compensating mode.
MODES: tuple[str, ...] = (
    "uncompensated",
    "inverse_hyperbolic",
    "inverse_quadratic",
    "linearized_dmax",
    "observer",
)
#: Shipped test-stand scenario every characterisation is derived from.
CHARACTERISATION = "characterisation"
#: Effect switched on, undeclared, in the calibration loop: the actuator's own thermal
#: expansion (0.4 nm/degC), which no voltage model explains and which moves the output with
#: temperature exactly where the compensation must act.
LOOP_EFFECT = "thermal_expansion"
#: Scenario the calibration loop's before/after tracking runs on.
LOOP_SCENARIO = "thesis_ac"
#: ``--long`` multiplies every scenario's time scale by this (slower thermal transients).
LONG_FACTOR = 5.0
#: Control rate of the closed-loop runs by default [Hz]: 50 samples per period of the 1 Hz
#: set points (the actuator is quasi-static); ``--long`` keeps each scenario's own rate.
DEFAULT_CONTROL_RATE = 50.0
#: Scenario keys a test stand copies from the scenario it characterises (same hardware).
_HARDWARE_KEYS = ("grid", "seed", "thermal", "sensors", "actuators", "effects")


def _now() -> str:
    return datetime.now(UTC).strftime("%Y%m%d-%H%M%S")


class Progress:
    """One line per event, prefixed with the elapsed wall time; thread-safe."""

    def __init__(self, stream: Any = sys.stdout) -> None:
        self._start = time.monotonic()
        self._stream = stream
        self._lock = threading.Lock()

    @property
    def elapsed(self) -> float:
        """Seconds since the start."""
        return time.monotonic() - self._start

    def __call__(self, text: str) -> None:
        """Print one progress line."""
        minutes, seconds = divmod(int(self.elapsed), 60)
        with self._lock:
            print(f"[demo {minutes:2d}:{seconds:02d}] {text}", file=self._stream, flush=True)


@dataclass(eq=False)  # identity: a job is one run
class Job:
    """One graph run: what to start and where its bag and logs go."""

    key: str
    scenario: str
    mode: str
    bag: Path
    log_dir: Path
    v_limit: float
    with_controllers: bool = True
    feedforward_params: Path | None = None
    plant: dict[str, ParamValue] = field(default_factory=dict)
    thermal: dict[str, ParamValue] = field(default_factory=dict)
    feedforward: dict[str, ParamValue] = field(default_factory=dict)
    record_extra: tuple[str, ...] = ()
    wall_s: float = 0.0


class DemoError(RuntimeError):
    """A step of the demo failed; the message is one readable line."""


class Runner:
    """Run jobs through the bring-up, ``jobs`` at a time, each graph in its own namespace."""

    def __init__(self, jobs: int, domain: int, progress: Progress) -> None:
        self._pool = ThreadPoolExecutor(max_workers=jobs)
        self._domain = domain
        self._free_slots = [f"run{i}" for i in range(jobs)]
        self._lock = threading.Lock()
        self._running: set[Bringup] = set()
        self._progress = progress
        self._stopping = threading.Event()

    def submit(self, job: Job) -> Future[Job]:
        """Queue a job; the future's result is the job with its wall time, or DemoError."""
        return self._pool.submit(self._run, job)

    def _run(self, job: Job) -> Job:
        if self._stopping.is_set():
            raise DemoError("interrupted")
        with self._lock:
            slot = self._free_slots.pop()
        config = GraphConfig(
            scenario=job.scenario,
            mode=job.mode,
            bag=job.bag,
            log_dir=job.log_dir,
            feedforward_params=job.feedforward_params,
            plant=job.plant,
            thermal=job.thermal,
            feedforward=job.feedforward,
            with_controllers=job.with_controllers,
            domain_id=self._domain,
            namespace=slot,
            wall_timeout=600.0,
            record_extra=job.record_extra,
        )
        bringup = Bringup(config, announce=lambda _text: None)
        with self._lock:
            self._running.add(bringup)
        started = time.monotonic()
        try:
            outcome = bringup.run()
        finally:
            with self._lock:
                self._running.discard(bringup)
                self._free_slots.append(slot)
        job.wall_s = time.monotonic() - started
        if outcome.exit_code != 0:
            raise DemoError(f"{job.key}: {outcome.reason} (logs: {job.log_dir})")
        return job

    def interrupt(self) -> None:
        """Stop every running graph and refuse queued ones."""
        self._stopping.set()
        with self._lock:
            for bringup in self._running:
                bringup.interrupt()

    def shutdown(self) -> None:
        """Wait for the workers to end."""
        self._pool.shutdown(wait=True, cancel_futures=True)


def _scenario_dict(name: str) -> dict[str, Any]:
    data = yaml.safe_load(resolve_scenario(name).read_text())
    if not isinstance(data, dict):
        raise DemoError(f"scenario {name} is not a YAML mapping")
    return data


def characterisation_scenario(
    scenario: str, out: Path, effects: dict[str, Any] | None = None, suffix: str = ""
) -> Path:
    """Write the characterisation of the hardware of ``scenario`` and return its path.

    The shipped ``characterisation`` scenario's program (voltage excitation, temperature
    ramp, interferometer noise) on the grid, seed, sensors, actuators and thermal set-up of
    ``scenario``: the same actuators with the same spread and the same sensors, as a test
    stand would measure the mirror it later controls. ``effects`` replaces the effects.
    """
    stand = _scenario_dict(CHARACTERISATION)
    source = _scenario_dict(scenario)
    for key in _HARDWARE_KEYS:
        if key in source:
            stand[key] = source[key]
        else:
            stand.pop(key, None)
    if effects is not None:
        stand["effects"] = effects
    label = Path(scenario).stem  # a shipped name, or a scenario file's stem
    stand["name"] = f"{CHARACTERISATION}_{label}{suffix}"
    stand["description"] = f"test stand for the hardware of {label}{suffix}"
    path = out / f"{stand['name']}.yaml"
    path.write_text(yaml.safe_dump(stand, sort_keys=False))
    load_scenario(str(path))  # fail here, readably, if the combination is invalid
    return path


def scenario_with_effects(scenario: str, out: Path, effects: dict[str, Any], suffix: str) -> Path:
    """Write ``scenario`` with ``effects`` replaced and return its path."""
    data = _scenario_dict(scenario)
    data["effects"] = effects
    data["name"] = f"{scenario}{suffix}"
    path = out / f"{data['name']}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    load_scenario(str(path))
    return path


def daq_clock_copy(bag: Path, out: Path, scenario: str) -> Path:
    """Write a copy of a lockstep test-stand bag stamped by the sample clock; return it.

    A lab's DAQ stamps every sample with its sample clock. The recorder stamps messages with
    its sim clock at reception instead, and under load it falls behind the plant, so runs of
    messages share one stamp (reported to the recorder's owners). The lockstep protocol gives
    every message its exact time from its index: step k's command and displacement at
    t_k = k / control_rate, sensor sample j at step j * sensor_every. The calibration reads
    this copy; the messages themselves are unchanged.
    """
    from es_msgs_py.bag import read_bag, write_array_bag
    from es_msgs_py.topics import COMMAND, DISPLACEMENT, HEAT_LOAD, TEMPERATURE_RAW

    sc = load_scenario(scenario)
    every = sensor_every(sc.control_rate, sc.sensor_rate)
    data = read_bag(bag, [COMMAND, DISPLACEMENT, HEAT_LOAD, TEMPERATURE_RAW])
    series = {}
    steps = {COMMAND: 1, DISPLACEMENT: 1, HEAT_LOAD: every, TEMPERATURE_RAW: every}
    for topic, step in steps.items():
        values = data[topic].values
        assert values is not None
        series[topic] = (np.arange(len(values)) * step / sc.control_rate, values)
    write_array_bag(out, series)
    return out


@dataclass
class Calibrated:
    """Output of one calibration: parameters YAML and calibration.json content."""

    params: Path
    summary: dict[str, Any]
    report: Path
    wall_s: float


def calibrate(bag: Path, out_dir: Path, log: Path) -> Calibrated:
    """Run ``es_feedforward calibrate BAG -o OUT_DIR`` and return what it wrote."""
    started = time.monotonic()
    with log.open("w") as handle:
        result = subprocess.run(
            [str(executable("es_feedforward", "calibrate")), str(bag), "-o", str(out_dir)],
            stdout=handle,
            stderr=subprocess.STDOUT,
            check=False,
        )
    if result.returncode != 0:
        tail = log.read_text(errors="replace").strip().splitlines()[-1:] or ["no output"]
        raise DemoError(f"calibrate failed on {bag}: {tail[0]} (log: {log})")
    params = sorted(out_dir.glob("*.yaml"))
    summary_file = out_dir / "calibration.json"
    if not params or not summary_file.is_file():
        raise DemoError(f"calibrate wrote no parameters YAML or calibration.json in {out_dir}")
    reports = sorted(out_dir.glob("*.md"))
    return Calibrated(
        params=params[0],
        summary=json.loads(summary_file.read_text()),
        report=reports[0] if reports else out_dir,
        wall_s=time.monotonic() - started,
    )


def without_compensation(params: Path, out: Path) -> Path:
    """Write a copy of a parameters YAML without its ``compensation.*`` entries."""
    data = yaml.safe_load(params.read_text())
    for node in data.values():
        ros = node.get("ros__parameters", {})
        for name in [n for n in ros if str(n).startswith("compensation.")]:
            del ros[name]
        compensation = ros.get("compensation")
        if isinstance(compensation, dict):
            del ros["compensation"]
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


@dataclass(frozen=True)
class Options:
    """Command-line options of the demo."""

    out: Path
    long: bool
    jobs: int
    scenarios: tuple[str, ...]
    modes: tuple[str, ...]
    loop: bool
    selfsensing: bool = True


def parse_args(argv: Sequence[str]) -> Options:
    """Parse the command line; exit 2 with one line when invalid."""
    parser = _OneLineParser(
        prog="demo",
        description="Characterise, calibrate, run every scenario and mode over ROS 2, report.",
    )
    parser.add_argument("--out", type=Path, help="output folder (default out/demo-<UTC time>)")
    parser.add_argument(
        "--long", action="store_true", help=f"{LONG_FACTOR:g}x longer (slower) temperature runs"
    )
    parser.add_argument("--jobs", type=int, default=3, help="graphs run in parallel (default 3)")
    parser.add_argument(
        "--scenarios", nargs="+", default=list(SCENARIOS), metavar="NAME", help="scenarios"
    )
    parser.add_argument("--modes", nargs="+", default=list(MODES), metavar="MODE", help="modes")
    parser.add_argument(
        "--no-loop", action="store_true", help="skip the calibration loop with an extra effect"
    )
    parser.add_argument(
        "--no-selfsensing", action="store_true",
        help=f"skip the self-sensing section (runs when {selfsensing_demo.SCENARIO} is selected)",
    )  # fmt: skip
    ns = parser.parse_args(list(argv))
    if not 1 <= ns.jobs <= 8:
        parser.error(f"--jobs must be 1..8, got {ns.jobs}")
    unknown = [m for m in ns.modes if m not in MODES]
    if unknown:
        parser.error(f"unknown mode(s) {unknown}; known: {list(MODES)}")
    for name in ns.scenarios:
        try:
            resolve_scenario(name)
        except ValueError as err:
            parser.error(str(err))
    modes = tuple(dict.fromkeys(["uncompensated", *ns.modes]))
    out = ns.out or Path("out") / f"demo-{_now()}"
    if out.exists() and any(out.iterdir()):
        parser.error(f"--out {out} exists and is not empty")
    return Options(
        out, ns.long, ns.jobs, tuple(ns.scenarios), modes, not ns.no_loop,
        not ns.no_selfsensing and selfsensing_demo.SCENARIO in ns.scenarios,
    )  # fmt: skip


def _domain() -> int:
    """Return the demo's ROS domain: ROS_DOMAIN_ID if set, else one picked from the PID."""
    given = os.environ.get("ROS_DOMAIN_ID")
    if given:
        return int(given)
    return process_domain_id()


class Demo:
    """The main job's steps (module docstring); :meth:`run` returns the report path."""

    def __init__(self, options: Options, progress: Progress) -> None:
        self.options = options
        self.progress = progress
        out = options.out
        self.dirs = {name: out / name for name in ("bags", "logs", "scenarios", "calibration")}
        for directory in self.dirs.values():
            directory.mkdir(parents=True, exist_ok=True)
        self.runner = Runner(options.jobs, _domain(), progress)
        self.time_scale_factor = LONG_FACTOR if options.long else 1.0

    # --- jobs -------------------------------------------------------------------------------

    def _plant_params(self, scenario: str, controllers: bool) -> dict[str, ParamValue]:
        sc = load_scenario(scenario)
        params: dict[str, ParamValue] = {}
        if self.time_scale_factor != 1.0:
            params["time_scale"] = sc.time_scale * self.time_scale_factor
        elif controllers:
            params["control_rate"] = DEFAULT_CONTROL_RATE
        return params

    def _job(
        self, key: str, scenario: str, mode: str, params: Path | None, controllers: bool = True
    ) -> Job:
        return Job(
            key=key,
            scenario=scenario,
            mode=mode,
            bag=self.dirs["bags"] / key,
            log_dir=self.dirs["logs"] / key,
            v_limit=load_scenario(scenario).actuators.v_limit,
            with_controllers=controllers,
            feedforward_params=params,
            plant=self._plant_params(scenario, controllers),
        )

    def _run_all(self, jobs: Sequence[Job], what: str) -> list[Job]:
        """Run jobs in parallel, showing each one's end; raise DemoError on the first failure."""
        total = len(jobs)
        futures = [self.runner.submit(job) for job in jobs]
        done: list[Job] = []
        for index, future in enumerate(futures, 1):
            job = future.result()
            done.append(job)
            self.progress(f"  {what} {index}/{total} {job.key}: {job.wall_s:.1f} s wall")
        return done

    # --- steps ------------------------------------------------------------------------------

    def characterise(self) -> dict[str, Job]:
        """Step 1: one test-stand run per distinct hardware among the scenarios."""
        stands: dict[str, Job] = {}
        by_content: dict[str, str] = {}
        for scenario in self.options.scenarios:
            path = characterisation_scenario(scenario, self.dirs["scenarios"])
            content = _hardware_signature(path)
            if content in by_content:
                stands[scenario] = stands[by_content[content]]
                continue
            by_content[content] = scenario
            key = f"characterisation-{scenario}"
            stands[scenario] = self._job(key, str(path), "uncompensated", None, controllers=False)
        unique = list({id(j): j for j in stands.values()}.values())
        self.progress(
            f"1/5 characterisation: {len(unique)} test-stand run(s), recorded like measured data"
        )
        self._run_all(unique, "test stand")
        return stands

    def calibrate_all(self, stands: dict[str, Job]) -> dict[str, Calibrated]:
        """Step 2: the calibration tool on every test-stand bag."""
        self.progress("2/5 calibration: es_feedforward calibrate on each test-stand bag")
        unique = list({job.bag: job for job in stands.values()}.values())
        with ThreadPoolExecutor(max_workers=self.options.jobs) as pool:
            done = dict(zip(unique, pool.map(self._calibrate, unique), strict=True))
        for job, calibrated in done.items():
            summary = calibrated.summary
            effects = [e.get("name", "?") for e in summary.get("effects", [])] or ["none"]
            self.progress(
                f"  {job.key}: held-out RMS {_nm(summary.get('heldout_rms_before_m'))} -> "
                f"{_nm(summary.get('heldout_rms_after_m'))}, effects: {', '.join(effects)} "
                f"({calibrated.wall_s:.1f} s)"
            )
        by_bag = {job.bag: calibrated for job, calibrated in done.items()}
        return {scenario: by_bag[job.bag] for scenario, job in stands.items()}

    def _calibrate(self, job: Job) -> Calibrated:
        """Run the calibration tool on a test-stand bag (its sample-clock copy)."""
        daq = daq_clock_copy(job.bag, self.dirs["bags"] / f"{job.key}-daq", job.scenario)
        out = self.dirs["calibration"] / job.key
        return calibrate(daq, out, self.dirs["logs"] / f"{job.key}-calibrate.log")

    def closed_loop(self, calibrated: dict[str, Calibrated]) -> list[RunResult]:
        """Step 3: every scenario with every mode, calibrated parameters, recorded."""
        jobs = [
            self._job(f"{scenario}-{mode}", scenario, mode, calibrated[scenario].params)
            for scenario in self.options.scenarios
            for mode in self.options.modes
        ]
        self.progress(
            f"3/5 closed loop: {len(self.options.scenarios)} scenarios x "
            f"{len(self.options.modes)} modes = {len(jobs)} runs over ROS 2 "
            f"({self.options.jobs} in parallel)"
        )
        done = self._run_all(jobs, "run")
        results = [self._analyse(job) for job in done]
        for r in results:
            self.progress(
                f"  {r.scenario} / {r.mode}: variation {_nm(r.metrics.variation_m)}, "
                f"RMS error {_nm(r.metrics.rms_error_m)}, invariants "
                f"{'held' if r.invariants.ok else 'FAILED: ' + '; '.join(r.invariants.failures)}"
            )
        return results

    def _analyse(self, job: Job) -> RunResult:
        sc = load_scenario(job.scenario)
        rate = job.plant.get("control_rate", sc.control_rate)
        control_rate = float(rate) if isinstance(rate, int | float) else sc.control_rate
        period = 1.0 / sc.setpoint.sine_frequency if sc.setpoint.sine_amplitude else None
        analysis: RunAnalysis = analyse_run(
            job.bag,
            job.log_dir,
            job.v_limit,
            control_rate=control_rate,
            sensor_rate=sc.sensor_rate,
            period_s=period,
        )
        return RunResult(
            scenario=Path(job.scenario).stem if job.scenario.endswith(".yaml") else job.scenario,
            mode=job.mode,
            bag=job.bag,
            metrics=analysis.metrics,
            slots=analysis.slots,
            run=analysis.run,
            invariants=analysis.invariants,
            wall_s=job.wall_s,
            sim_s=analysis.sim_s,
        )

    def calibration_loop(self) -> tuple[str, list[RunResult]]:
        """Step 4: an undeclared effect, found by the tool; tracking before and after."""
        self.progress(
            f"4/5 calibration loop: test stand with an effect the model lacks, calibrate, "
            f"track {LOOP_SCENARIO} before/after"
        )
        effects = {LOOP_EFFECT: {"enabled": True}}
        stand_path = characterisation_scenario(
            LOOP_SCENARIO, self.dirs["scenarios"], effects, suffix=f"_{LOOP_EFFECT}"
        )
        stand = self._job(
            f"loop-characterisation-{LOOP_EFFECT}", str(stand_path), "uncompensated", None, False
        )
        self._run_all([stand], "test stand")
        calibrated = self._calibrate(stand)
        before_params = without_compensation(
            calibrated.params, self.dirs["calibration"] / f"{stand.key}-without-compensation.yaml"
        )
        scenario_path = scenario_with_effects(
            LOOP_SCENARIO, self.dirs["scenarios"], effects, suffix=f"_{LOOP_EFFECT}"
        )
        jobs = [
            self._job(f"loop-{label}", str(scenario_path), "inverse_hyperbolic", params)
            for label, params in (("before", before_params), ("after", calibrated.params))
        ]
        done = self._run_all(jobs, "loop run")
        runs = [self._analyse(job) for job in done]
        for run, label in zip(runs, ("before", "after"), strict=True):
            run.mode = f"inverse_hyperbolic ({label})"
        text = loop_markdown(calibrated, runs, stand.bag)
        return text, runs

    def goal_markdown(self, results: Sequence[RunResult], calibrated: dict[str, Calibrated]) -> str:
        """Return the goal check against the thesis and where the remaining variation comes from."""
        from dataclasses import replace as with_changes

        from es_bringup.goal import (
            estimate_error,
            offline_metrics,
            settle_time,
            settled_metrics,
        )
        from es_feedforward.feedforward import Mode
        from es_feedforward.param_file import read_params_file

        grouped: dict[str, dict[str, RunResult]] = {}
        for r in results:
            grouped.setdefault(r.scenario, {})[r.mode] = r
        lines = [
            "## Goal: inverse_hyperbolic >= 95 % reduction on both thesis scenarios",
            "",
            "Default simulator, feedforward with the calibrated parameters. To show where the "
            "rest comes from, the same scenario also ran offline (plant and feedforward cores, "
            "no ROS) with the feedforward given the simulator's true actuator temperature: "
            "with the calibrated parameters, and with the simulator's true parameters.",
            "",
            "| scenario | simulator | reduction | closed loop [nm] | settled periods only "
            "[nm] (reduction) | offline, true T, calibrated [nm] | offline, true T, true "
            "parameters [nm] | uncompensated [nm] | goal |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        notes: list[str] = []
        for name in ("thesis_ac", "thesis_dc_ac"):
            modes = grouped.get(name, {})
            run, base = modes.get("inverse_hyperbolic"), modes.get("uncompensated")
            if run is None or base is None or name not in calibrated:
                continue
            sc = load_scenario(name)
            if self.time_scale_factor != 1.0:  # what _plant_params asks of the plant node
                sc = load_scenario(name, sc.time_scale * self.time_scale_factor)
            else:
                sc = sc.with_overrides(control_rate=DEFAULT_CONTROL_RATE)
            config = with_changes(
                read_params_file(calibrated[name].params), mode=Mode.INVERSE_HYPERBOLIC
            )
            period = 1.0 / sc.setpoint.sine_frequency
            cal = offline_metrics(sc, config, period)
            true = offline_metrics(sc, config, period, true_params=True)
            cut = 1.0 - run.metrics.variation_m / base.metrics.variation_m
            settled = settled_metrics(run.run, period, sc, skip_s=period)
            settled_base = settled_metrics(base.run, period, sc, skip_s=period)
            settled_text = "no step"
            if settled is not None and settled_base is not None:
                settled_cut = 1.0 - settled.variation_m / settled_base.variation_m
                settled_text = f"{settled.variation_m * 1e9:.3f} ({100 * settled_cut:.1f} %)"
                notes.append(
                    f"{name}: the settled figure leaves out the periods within "
                    f"{settle_time(sc):.2g} s of a base step (5 x the face-sheet, actuator and "
                    "sensor-lag time constants)."
                )
            notes.append(
                f"{name}: largest error of the temperature estimate in force against the "
                f"simulator's true actuator temperature: {estimate_error(run.run, sc):.2f} degC."
            )
            lines.append(
                f"| {name} | {_simulator_text(sc)} | {100 * cut:.1f} % | "
                f"{run.metrics.variation_m * 1e9:.3f} | {settled_text} | "
                f"{cal.variation_m * 1e9:.3f} | {true.variation_m * 1e9:.3f} | "
                f"{base.metrics.variation_m * 1e9:.3f} | {'met' if cut >= 0.95 else 'NOT met'} |"
            )
        lines += [
            "",
            "Reading the table: closed loop minus the offline run with calibrated parameters "
            "is what the temperature estimate adds (sensor noise and quantisation through "
            "the thermal node, and above all its error right after a base-temperature step); "
            "offline calibrated minus offline true parameters is what the calibration "
            "leaves; the last is the floor of the model and of the discrete control step.",
            "",
            "Why thesis_ac is the harder of the two: it steps the "
            "base temperature by 2 degC at once. The actuator follows within its time "
            "constant, the lagging sensor later, and the thermal node's estimate (a base "
            "plate it models as drifting slowly) is off most until the first "
            "samples after each step (largest estimate errors below); at ~3 %/degC on up to "
            "100 nm each 0.1 degC of error is up to 0.3 nm while it lasts, and the thesis's "
            "variation "
            "(the largest deviation of any averaged period) takes exactly that period. The "
            "thesis measured each level only after the stage had reached equilibrium (and "
            "its Peltier stage ramps at ~1.5 min per degC rather than jumping): the settled "
            "column is that measurement. thesis_dc_ac ramps slowly, so its estimate keeps up.",
        ]
        if notes:
            lines += ["", *notes]
        return "\n".join(lines)

    def selfsensing(self, calibrated: Calibrated) -> str:
        """Step 4b: resonance test stand, calibrate_resonance, the three sensor set-ups."""
        ss = selfsensing_demo
        self.progress(
            f"4/5 self-sensing: test stand with resonance sweeps, calibrate_resonance, "
            f"{ss.SCENARIO} with 4 NTCs / 4 NTCs + self-sensing / an NTC per actuator"
        )
        d = self.dirs
        stand_path = ss.stand_scenario(
            characterisation_scenario(ss.SCENARIO, d["scenarios"]), d["scenarios"]
        )
        stand = self._job("selfsensing-stand", str(stand_path), "uncompensated", None, False)
        stand.record_extra = (RESONANCE,)
        self._run_all([stand], "test stand")
        try:
            daq = ss.sample_clock_copy(stand.bag, d["bags"] / f"{stand.key}-daq", str(stand_path))
            params = ss.calibrate(
                daq, d["calibration"] / stand.key / "thermal_params.yaml",
                d["logs"] / f"{stand.key}-calibrate.log",
            )  # fmt: skip
        except (ss.SelfSensingError, ValueError) as err:
            raise DemoError(str(err)) from None
        scenarios = ss.case_scenarios(resolve_scenario(ss.SCENARIO), d["scenarios"])
        jobs = []
        for case, path in scenarios.items():
            job = self._job(
                f"selfsensing-{case}", str(path), "inverse_hyperbolic", calibrated.params
            )
            job.record_extra = (RESONANCE,)
            if case == "ntc_selfsensing":
                job.thermal = params
            jobs.append(job)
        done = self._run_all(jobs, "run")
        figures = {}
        for case, job in zip(scenarios, done, strict=True):
            result = self._analyse(job)
            rate = job.plant.get("control_rate")
            control_rate = (
                float(rate)
                if isinstance(rate, int | float)
                else load_scenario(job.scenario).control_rate
            )
            errors = ss.temperature_errors(job.bag, job.scenario, control_rate)
            figures[case] = ss.case_figures(case, errors, result.metrics.variation_m)
            self.progress(
                f"  {case}: temperature RMS {figures[case].rms:.4f} degC, worst actuator "
                f"{figures[case].worst:.4f} degC, variation {_nm(result.metrics.variation_m)}"
            )
        figure_dir = self.options.out / "figures"
        figure_dir.mkdir(parents=True, exist_ok=True)
        ss.plot_maps(figures, figure_dir / "selfsensing_error_maps.png")
        bags = {case: job.bag for case, job in zip(scenarios, done, strict=True)}
        return ss.section_markdown(figures, "figures/selfsensing_error_maps.png", params, bags)

    def run(self) -> Path:
        """Run every step; return the report path."""
        stands = self.characterise()
        calibrated = self.calibrate_all(stands)
        results = self.closed_loop(calibrated)
        goal = self.goal_markdown(results, calibrated)
        loop_text, loop_runs = self.calibration_loop() if self.options.loop else ("", [])
        selfsensing = (
            self.selfsensing(calibrated[selfsensing_demo.SCENARIO])
            if self.options.selfsensing
            else ""
        )
        self.progress("5/5 report")
        preamble = [story_markdown(stands, calibrated, self.options)]
        if loop_text:
            preamble.append(loop_text)
        inputs = ReportInputs(
            runs=results,
            bag_dir=self.dirs["bags"],
            command=" ".join(["scripts/demo", *sys.argv[1:]]),
            wall_s=self.progress.elapsed,
            preamble=preamble,
            notes=[
                goal,
                *([selfsensing] if selfsensing else []),
                time_scale_markdown(self.options, self.time_scale_factor),
            ],
        )
        del loop_runs
        return write_report(inputs, self.options.out)


def _hardware_signature(path: Path) -> str:
    """Return what makes two test stands measure the same hardware.

    Without manufacturing spread and sensor offsets the seed draws nothing but noise, so it
    does not tell two actuators apart.
    """
    sc = load_scenario(str(path))
    data = yaml.safe_load(path.read_text())
    keys = list(_HARDWARE_KEYS)
    if not sc.actuators.spread and sc.sensors.offset_sd == 0 and sc.sensors.offsets is None:
        keys.remove("seed")
    return json.dumps({k: data.get(k) for k in keys}, sort_keys=True, default=str)


def _simulator_text(sc: Scenario) -> str:
    """Return what of the default simulator's imperfections a scenario has on, in words."""
    spread = ", ".join(f"{k} {100 * v:g} %" for k, v in sc.actuators.spread.items()) or "none"
    lag = sc.effects.sensor_lag
    lag_text = f"lag {lag.tau_s / sc.time_scale:g} s physical" if lag.enabled else "no lag"
    return (
        f"spread {spread} (seed {sc.seed}); sensor noise {sc.sensors.noise_sd:g} degC rms, "
        f"{lag_text}"
    )


def _nm(value: object) -> str:
    if not isinstance(value, int | float):
        return "n/a"
    return f"{value * 1e9:.3f} nm"


def story_markdown(
    stands: dict[str, Job], calibrated: dict[str, Calibrated], options: Options
) -> str:
    """Return the characterisation and calibration part of the report."""
    lines = [
        "## 1. Characterisation: the simulator as a test stand",
        "",
        "No feedforward: the plant drives every actuator with a signal-generator voltage "
        "program while the base temperature ramps 40 -> 52 -> 40 degC, and the recorder "
        "stores /dm/command, /dm/displacement (with interferometer noise) and the raw "
        "temperatures exactly as measured data would be stored. One run per distinct "
        "hardware (grid, seed, actuators, sensors) of the scenarios below.",
        "",
        "| scenario | test-stand bag | wall [s] |",
        "|---|---|---|",
    ]
    lines += [f"| {s} | `{j.bag}` | {j.wall_s:.1f} |" for s, j in stands.items()]
    lines += [
        "",
        "## 2. Calibration: `es_feedforward calibrate` on each test-stand bag",
        "",
        "The tool is told nothing about how the data were made. Its parameters YAML is what "
        "every closed-loop run below loads into the feedforward node.",
        "",
        "| scenario | held-out RMS before [nm] | after [nm] | effects accepted | parameters "
        "| tool report |",
        "|---|---|---|---|---|---|",
    ]
    for scenario, cal in calibrated.items():
        effects = ", ".join(e.get("name", "?") for e in cal.summary.get("effects", [])) or "none"
        lines.append(
            f"| {scenario} | {_nm(cal.summary.get('heldout_rms_before_m'))} | "
            f"{_nm(cal.summary.get('heldout_rms_after_m'))} | {effects} | `{cal.params}` | "
            f"`{cal.report}` |"
        )
    del options
    return "\n".join(lines)


def loop_markdown(calibrated: Calibrated, runs: Sequence[RunResult], bag: Path) -> str:
    """Return the calibration loop part of the report."""
    summary = calibrated.summary
    lines = [
        f"## 3. One calibration loop end to end: `{LOOP_EFFECT}`",
        "",
        f"A test-stand bag (`{bag}`) of the {LOOP_SCENARIO} actuator with `{LOOP_EFFECT}` "
        "switched on in the simulator; the calibration tool is not told about it.",
        "",
        f"- held-out RMS error of the basic model: {_nm(summary.get('heldout_rms_before_m'))}",
    ]
    for effect in summary.get("effects", []):
        params = ", ".join(f"{k} = {v:.4g}" for k, v in effect.get("parameters", {}).items())
        lines.append(
            f"- effect found: `{effect.get('name')}` ({params}); held-out RMS "
            f"{_nm(effect.get('rms_before_m'))} -> {_nm(effect.get('rms_after_m'))}"
        )
    if not summary.get("effects"):
        lines.append("- effect found: none (the tool accepted no effect)")
    lines.append(
        f"- held-out RMS error after the loop: {_nm(summary.get('heldout_rms_after_m'))}"
    )
    unexplained = summary.get("unexplained") or []
    lines.append(f"- left unexplained: {'; '.join(map(str, unexplained)) or 'nothing'}")
    lines += [
        "",
        f"Closed loop on {LOOP_SCENARIO} with `{LOOP_EFFECT}` on, mode inverse_hyperbolic, "
        "with the calibrated parameters without (before) and with (after) the effect's "
        "compensation:",
        "",
        "| parameters | RMS error [nm] | max error [nm] | variation [nm] | bag |",
        "|---|---|---|---|---|",
    ]
    for run in runs:
        m = run.metrics
        lines.append(
            f"| {run.mode} | {m.rms_error_m * 1e9:.3f} | {m.max_error_m * 1e9:.3f} | "
            f"{m.variation_m * 1e9:.3f} | `{run.bag}` |"
        )
    lines += [
        "",
        "The compensation subtracts the expansion from the set point. Where the set point "
        "is near 0 nm (the trough of the 0-100 nm sine) that asks for a contraction an "
        "electrostrictive actuator cannot make (it only expands, for either sign of the "
        "voltage): there the expansion stays, so the maximum error and the variation (a "
        "maximum over the period) barely change while the RMS error falls.",
    ]
    return "\n".join(lines)


def time_scale_markdown(options: Options, factor: float) -> str:
    """Return where time scales are shortened against the thesis."""
    lines = [
        "## Time scales",
        "",
        "Temperature ranges and set points are the thesis's; the slow thermal parts are "
        "shortened (each scenario's `time_scale` multiplies its duration, temperature "
        "profile, exposure schedule and thermal time constants; set-point frequencies, "
        "rates and the transport delay are not scaled):",
        "",
        "| scenario | time_scale | simulated [s] | physical length [s] |",
        "|---|---|---|---|",
    ]
    for name in (CHARACTERISATION, *options.scenarios):
        sc = load_scenario(name)
        scale = sc.time_scale * factor
        lines.append(
            f"| {name} | {scale:g} | {sc.duration * factor:g} | {sc.duration / sc.time_scale:g} |"
        )
    if factor == 1.0:
        lines += ["", f"`--long` runs every scenario {LONG_FACTOR:g}x longer."]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo from the command line; return the exit code."""
    options = parse_args(sys.argv[1:] if argv is None else argv)
    progress = Progress()
    options.out.mkdir(parents=True, exist_ok=True)
    progress(f"output folder: {options.out}")
    demo = Demo(options, progress)
    interrupted: Callable[[], None] = demo.runner.interrupt
    try:
        report = demo.run()
    except KeyboardInterrupt:
        interrupted()
        progress("interrupted; every node stopped")
        return 130
    except (DemoError, ValueError, OSError) as err:
        demo.runner.interrupt()
        print(f"demo: error: {err}", file=sys.stderr)
        return 1
    finally:
        demo.runner.shutdown()
    progress(f"done in {progress.elapsed:.0f} s. Report: {report}")
    progress(f"summary: {options.out / 'summary.json'}; bags: {demo.dirs['bags']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
