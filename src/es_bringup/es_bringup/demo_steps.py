"""The demo's steps (see :mod:`es_bringup.demo`), each run a graph through the bring-up.

Characterise, calibrate, closed loop, calibration loop, self-sensing, report.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from es_bringup import selfsensing_demo
from es_bringup.analysis import RunAnalysis, analyse_run
from es_bringup.bringup import ParamValue
from es_bringup.demo_calibration import (
    LOOP_EFFECT,
    LOOP_SCENARIO,
    Calibrated,
    calibrate,
    characterisation_scenario,
    daq_clock_copy,
    hardware_signature,
    health_lines,
    scenario_with_effects,
    without_compensation,
)
from es_bringup.demo_options import DEFAULT_CONTROL_RATE, LONG_FACTOR, Options
from es_bringup.demo_runs import DemoError, Job, Progress, Runner, demo_domain
from es_bringup.demo_text import (
    goal_markdown,
    loop_markdown,
    nm,
    story_markdown,
    time_scale_markdown,
)
from es_bringup.report import ReportInputs, RunResult, write_report
from es_msgs_py.topics import RESONANCE
from es_sim_plant.scenario import load_scenario, resolve_scenario


class Demo:
    """The main job's steps (module docstring); :meth:`run` returns the report path."""

    def __init__(self, options: Options, progress: Progress) -> None:
        self.options = options
        self.progress = progress
        out = options.out
        self.dirs = {name: out / name for name in ("bags", "logs", "scenarios", "calibration")}
        for directory in self.dirs.values():
            directory.mkdir(parents=True, exist_ok=True)
        self.runner = Runner(options.jobs, demo_domain(), progress)
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
        self,
        key: str,
        scenario: str,
        mode: str,
        params: Path | None,
        controllers: bool = True,
        *,
        thermal_params: Path | None = None,
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
            thermal_params=thermal_params,
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
            content = hardware_signature(path)
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
        self.progress("2/5 calibration: es_calibration calibrate on each test-stand bag")
        unique = list({job.bag: job for job in stands.values()}.values())
        with ThreadPoolExecutor(max_workers=self.options.jobs) as pool:
            done = dict(zip(unique, pool.map(self._calibrate, unique), strict=True))
        for job, calibrated in done.items():
            summary = calibrated.summary
            effects = [e.get("name", "?") for e in summary.get("effects", [])] or ["none"]
            self.progress(
                f"  {job.key}: held-out RMS {nm(summary.get('heldout_rms_before_m'))} -> "
                f"{nm(summary.get('heldout_rms_after_m'))}, effects: {', '.join(effects)} "
                f"({calibrated.wall_s:.1f} s)"
            )
            for line in health_lines(summary):
                self.progress(f"    {line}")
        by_bag = {job.bag: calibrated for job, calibrated in done.items()}
        return {scenario: by_bag[job.bag] for scenario, job in stands.items()}

    def _calibrate(self, job: Job) -> Calibrated:
        """Run the calibration tool on a test-stand bag (its sample-clock copy)."""
        daq = daq_clock_copy(job.bag, self.dirs["bags"] / f"{job.key}-daq", job.scenario)
        out = self.dirs["calibration"] / job.key
        scale = job.plant.get("time_scale", load_scenario(job.scenario).time_scale)
        time_scale = float(scale) if isinstance(scale, int | float) else 1.0
        return calibrate(daq, out, self.dirs["logs"] / f"{job.key}-calibrate.log", time_scale)

    def closed_loop(self, calibrated: dict[str, Calibrated]) -> list[RunResult]:
        """Step 3: every scenario with every mode, calibrated parameters, recorded."""
        jobs = [
            self._job(
                f"{scenario}-{mode}", scenario, mode, calibrated[scenario].params,
                thermal_params=calibrated[scenario].thermal_params,
            )
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
                f"  {r.scenario} / {r.mode}: variation {nm(r.metrics.variation_m)}, "
                f"RMS error {nm(r.metrics.rms_error_m)}, invariants "
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

    def calibration_loop(self) -> str:
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
        # before: the law alone (no compensation, no sensor calibration); after: both files
        jobs = [
            self._job(f"loop-{label}", str(scenario_path), "inverse_hyperbolic", params,
                      thermal_params=thermal)
            for label, params, thermal in (
                ("before", before_params, None),
                ("after", calibrated.params, calibrated.thermal_params),
            )
        ]
        done = self._run_all(jobs, "loop run")
        runs = [self._analyse(job) for job in done]
        for run, label in zip(runs, ("before", "after"), strict=True):
            run.mode = f"inverse_hyperbolic ({label})"
        return loop_markdown(calibrated, runs, stand.bag)

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
                f"{figures[case].worst:.4f} degC, variation {nm(result.metrics.variation_m)}"
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
        goal = goal_markdown(results, calibrated, self.time_scale_factor)
        loop_text = self.calibration_loop() if self.options.loop else ""
        selfsensing = (
            self.selfsensing(calibrated[selfsensing_demo.SCENARIO])
            if self.options.selfsensing
            else ""
        )
        self.progress("5/5 report")
        preamble = [story_markdown(stands, calibrated)]
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
        return write_report(inputs, self.options.out)
