"""The demo's report texts (Markdown sections of ``report.md``).

The story of the characterisation and calibration, the calibration loop, the goal check
against the thesis and the time scales.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from es_bringup.demo_calibration import (
    CHARACTERISATION,
    LOOP_EFFECT,
    LOOP_SCENARIO,
    Calibrated,
    health_lines,
)
from es_bringup.demo_options import DEFAULT_CONTROL_RATE, LONG_FACTOR, Options
from es_bringup.demo_runs import Job
from es_bringup.report import RunResult
from es_sim_plant.scenario import Scenario, load_scenario


def goal_markdown(
    results: Sequence[RunResult], calibrated: dict[str, Calibrated], time_scale_factor: float
) -> str:
    """Return the goal check against the thesis and where the remaining variation comes from.

    Args:
        results: the closed-loop runs (scenario and mode of each).
        calibrated: the calibration of each scenario's hardware.
        time_scale_factor: what ``--long`` multiplies every time scale by (1 without).

    """
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
        if time_scale_factor != 1.0:  # what the demo asks of the plant node
            sc = load_scenario(name, sc.time_scale * time_scale_factor)
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
            f"| {name} | {simulator_text(sc)} | {100 * cut:.1f} % | "
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


def simulator_text(sc: Scenario) -> str:
    """Return what of the default simulator's imperfections a scenario has on, in words."""
    spread = ", ".join(f"{k} {100 * v:g} %" for k, v in sc.actuators.spread.items()) or "none"
    lag = sc.effects.sensor_lag
    lag_text = f"lag {lag.tau_s / sc.time_scale:g} s physical" if lag.enabled else "no lag"
    return (
        f"spread {spread} (seed {sc.seed}); sensor noise {sc.sensors.noise_sd:g} degC rms, "
        f"{lag_text}"
    )


def nm(value: object) -> str:
    """Return a length [m] as ``"x.xxx nm"``, or ``"n/a"`` when it is not a number."""
    if not isinstance(value, int | float):
        return "n/a"
    return f"{value * 1e9:.3f} nm"


def story_markdown(stands: dict[str, Job], calibrated: dict[str, Calibrated]) -> str:
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
        "## 2. Calibration: `es_calibration calibrate` on each test-stand bag",
        "",
        "The tool is told nothing about how the data were made. Its parameters YAML is what "
        "every closed-loop run below loads into the feedforward node.",
        "",
        "| scenario | held-out RMS before [nm] | after [nm] | effects accepted | verdict "
        "| health findings | parameters | tool report |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for scenario, cal in calibrated.items():
        effects = ", ".join(e.get("name", "?") for e in cal.summary.get("effects", [])) or "none"
        lines.append(
            f"| {scenario} | {nm(cal.summary.get('heldout_rms_before_m'))} | "
            f"{nm(cal.summary.get('heldout_rms_after_m'))} | {effects} | "
            f"{(cal.summary.get('verdict') or {}).get('level', '-')} | "
            f"{len((cal.summary.get('health') or {}).get('findings') or [])} | `{cal.params}` | "
            f"`{cal.report}` |"
        )
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
        f"- held-out RMS error of the basic model: {nm(summary.get('heldout_rms_before_m'))}",
    ]
    for effect in summary.get("effects", []):
        params = ", ".join(f"{k} = {v:.4g}" for k, v in effect.get("parameters", {}).items())
        lines.append(
            f"- effect found: `{effect.get('name')}` ({params}); held-out RMS "
            f"{nm(effect.get('rms_before_m'))} -> {nm(effect.get('rms_after_m'))}"
        )
    if not summary.get("effects"):
        lines.append("- effect found: none (the tool accepted no effect)")
    lines.append(f"- held-out RMS error after the loop: {nm(summary.get('heldout_rms_after_m'))}")
    unexplained = summary.get("unexplained") or []
    lines.append(f"- left unexplained: {'; '.join(map(str, unexplained)) or 'nothing'}")
    lines += [f"- {line}" for line in health_lines(summary)]
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
