"""The main job's report: summary.json, Markdown and PNG figures of the closed-loop runs.

Pure (numpy + matplotlib, no rclpy). Takes the metrics of every (scenario, mode) run and
writes, into one output folder:

- ``summary.json``: ``{"scenarios": {NAME: {MODE: {"variation_m", "reduction",
  "rms_error_m", "max_error_m"}}}, "bag": PATH}`` (reduction as a fraction against
  ``uncompensated``; ``PATH`` is the folder holding one bag per run);
- ``report.md`` and ``figures/*.png``: per scenario the averaged output periods over
  temperature, the deviation from the mid-range reference versus temperature, and for a grid
  the per-actuator error maps.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only; never a window

import matplotlib.pyplot as plt
import numpy as np

from es_bringup.invariants import InvariantReport
from es_bringup.metrics import AlignedRun, PeriodSlots, RunMetrics, reduction

BASELINE_MODE = "uncompensated"
NM = 1e9

#: The thesis's hardware results (quadratic inverse model), chapter 4.
THESIS_RESULTS: dict[str, dict[str, float | str]] = {
    "thesis_ac": {
        "uncompensated_m": 32e-9,
        "compensated_m": 4e-9,
        "reduction": 0.87,
        "what": "0-100 nm at 1 Hz, 40 -> 52 degC in discrete steps (section 4-1)",
    },
    "thesis_dc_ac": {
        "uncompensated_m": 9e-9,
        "compensated_m": 2.5e-9,
        "reduction": 0.75,
        "what": "100 nm DC + 25 nm at 1 Hz, 41 -> 51 degC continuous; periods normalised "
        "about the DC set point (section 4-2)",
    },
}


@dataclass
class RunResult:
    """Everything the report needs about one closed-loop run."""

    scenario: str
    mode: str
    bag: Path
    metrics: RunMetrics
    slots: PeriodSlots
    run: AlignedRun
    invariants: InvariantReport
    wall_s: float
    sim_s: float


@dataclass
class ReportInputs:
    """The runs plus the story around them (each part optional)."""

    runs: Sequence[RunResult]
    bag_dir: Path
    command: str = ""
    wall_s: float = 0.0
    #: Markdown paragraphs placed before the scenario results (characterisation,
    #: calibration, the calibration loop), in order.
    preamble: Sequence[str] = ()
    #: Markdown paragraphs placed after the results (time scales, goal discussion).
    notes: Sequence[str] = ()
    #: Extra figures already written into the output folder: (relative path, caption).
    extra_figures: Sequence[tuple[str, str]] = field(default_factory=tuple)


def by_scenario(runs: Sequence[RunResult]) -> dict[str, dict[str, RunResult]]:
    """Group runs as ``{scenario: {mode: run}}`` in the order given."""
    grouped: dict[str, dict[str, RunResult]] = {}
    for run in runs:
        grouped.setdefault(run.scenario, {})[run.mode] = run
    return grouped


def reductions(modes: Mapping[str, RunResult]) -> dict[str, float]:
    """Reduction of each mode's variation against the scenario's ``uncompensated`` run."""
    base = modes.get(BASELINE_MODE)
    if base is None:
        return dict.fromkeys(modes, math.nan)
    return {m: reduction(r.metrics.variation_m, base.metrics.variation_m) for m, r in modes.items()}


def _json_number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def summary(runs: Sequence[RunResult], bag_dir: Path) -> dict[str, Any]:
    """Return the summary.json document (NaN becomes null)."""
    scenarios: dict[str, Any] = {}
    for name, modes in by_scenario(runs).items():
        cut = reductions(modes)
        scenarios[name] = {
            mode: {
                "variation_m": _json_number(r.metrics.variation_m),
                "reduction": _json_number(cut[mode]),
                "rms_error_m": _json_number(r.metrics.rms_error_m),
                "max_error_m": _json_number(r.metrics.max_error_m),
            }
            for mode, r in modes.items()
        }
    return {"scenarios": scenarios, "bag": str(bag_dir)}


def _focus_actuator(modes: Mapping[str, RunResult]) -> int:
    """Return the actuator shown in line plots: the one the baseline varies most on."""
    base = modes.get(BASELINE_MODE) or next(iter(modes.values()))
    return int(np.argmax(base.slots.variation))


def plot_periods(name: str, modes: Mapping[str, RunResult], path: Path) -> None:
    """Averaged output period per temperature slot (colour) against the set point, per mode."""
    actuator = _focus_actuator(modes)
    count = len(modes)
    fig, axes = plt.subplots(1, count, figsize=(3.2 * count, 3.2), sharey=True, squeeze=False)
    temps = np.concatenate([r.slots.temperature[:, actuator] for r in modes.values()])
    temps = temps[np.isfinite(temps)]
    norm = plt.Normalize(float(temps.min()), float(temps.max()))
    cmap = plt.get_cmap("coolwarm")
    for ax, (mode, result) in zip(axes[0], modes.items(), strict=True):
        slots = result.slots
        for s in range(slots.temperature.shape[0]):
            temp = slots.temperature[s, actuator]
            if np.isfinite(temp):
                ax.plot(slots.phase, slots.mean_output[s, actuator] * NM, color=cmap(norm(temp)))
        ref = slots.reference_slot[actuator]
        ax.plot(slots.phase, slots.mean_setpoint[ref, actuator] * NM, "k--", label="set point")
        ax.set_title(mode, fontsize=9)
        ax.set_xlabel("time in period [s]")
    axes[0][0].set_ylabel("displacement [nm]")
    axes[0][0].legend(fontsize=7, loc="upper left")
    fig.colorbar(
        plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes[0].tolist(), label="temperature [degC]"
    )
    fig.suptitle(f"{name}: averaged output period per temperature slot (actuator {actuator})")
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)


def plot_error_vs_temperature(name: str, modes: Mapping[str, RunResult], path: Path) -> None:
    """Deviation from the mid-range reference, and tracking error, against temperature."""
    actuator = _focus_actuator(modes)
    fig, (dev_ax, err_ax) = plt.subplots(1, 2, figsize=(10, 3.6))
    for mode, result in modes.items():
        slots = result.slots
        ref = slots.reference_slot[actuator]
        temp = slots.temperature[:, actuator]
        filled = np.flatnonzero(np.isfinite(temp))
        filled = filled[np.argsort(temp[filled])]
        outputs = slots.mean_output[filled, actuator]
        deviation = np.max(np.abs(outputs - slots.mean_output[ref, actuator]), axis=1)
        error = outputs - slots.mean_setpoint[filled, actuator]
        rms = np.sqrt(np.mean(error**2, axis=1))
        dev_ax.plot(temp[filled], deviation * NM, ".-", label=mode)
        err_ax.plot(temp[filled], rms * NM, ".-", label=mode)
    dev_ax.set_title("max deviation from the mid-range period", fontsize=9)
    err_ax.set_title("RMS tracking error of the averaged period", fontsize=9)
    for ax in (dev_ax, err_ax):
        ax.set_xlabel("temperature [degC]")
        ax.set_ylabel("[nm]")
        ax.set_yscale("symlog", linthresh=0.1)
        ax.grid(alpha=0.3)
    err_ax.legend(fontsize=7)
    fig.suptitle(f"{name}: error against temperature (actuator {actuator})")
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)


def plot_error_maps(name: str, modes: Mapping[str, RunResult], path: Path) -> None:
    """Per-actuator RMS tracking error over the grid, one panel per mode, one colour scale."""
    maps = {m: r.metrics.rms_error_map * NM for m, r in modes.items()}
    top = max(float(np.max(v)) for v in maps.values())
    count = len(maps)
    fig, axes = plt.subplots(1, count, figsize=(2.8 * count, 2.9), squeeze=False)
    image = None
    for ax, (mode, values) in zip(axes[0], maps.items(), strict=True):
        image = ax.imshow(values, cmap="viridis", vmin=0.0, vmax=top, origin="upper")
        ax.set_title(f"{mode}\nmax {np.max(values):.3g} nm", fontsize=8)
        ax.set_xlabel("col")
    axes[0][0].set_ylabel("row")
    if image is not None:
        fig.colorbar(image, ax=axes[0].tolist(), label="RMS tracking error [nm]")
    fig.suptitle(f"{name}: per-actuator RMS tracking error")
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)


def _pct(value: float) -> str:
    return f"{100 * value:.1f} %" if math.isfinite(value) else "n/a"


def _results_table(modes: Mapping[str, RunResult]) -> list[str]:
    cut = reductions(modes)
    base = modes.get(BASELINE_MODE)
    lines = [
        "| mode | variation [nm] | reduction | AC-only variation [nm] | AC-only reduction "
        "| RMS error [nm] | max error [nm] | invariants |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for mode, r in modes.items():
        m = r.metrics
        ac_cut = reduction(m.ac_variation_m, base.metrics.ac_variation_m) if base else math.nan
        lines.append(
            f"| {mode} | {m.variation_m * NM:.3f} | {_pct(cut[mode])} | "
            f"{m.ac_variation_m * NM:.3f} | {_pct(ac_cut)} | {m.rms_error_m * NM:.3f} | "
            f"{m.max_error_m * NM:.3f} | {'held' if r.invariants.ok else 'FAILED'} |"
        )
    return lines


def _thesis_line(name: str) -> str:
    ref = THESIS_RESULTS.get(name)
    if ref is None:
        return "No thesis result for this scenario (it is the product's own use case)."
    return (
        f"Thesis, hardware, quadratic inverse: {float(ref['uncompensated_m']) * NM:.1f} nm "
        f"uncompensated -> {float(ref['compensated_m']) * NM:.1f} nm compensated, "
        f"{_pct(float(ref['reduction']))} reduction ({ref['what']})."
    )


def _thesis_table(runs: Sequence[RunResult]) -> list[str]:
    """Return the thesis's two hardware results beside this run's figures."""
    grouped = by_scenario(runs)
    lines = [
        "| scenario | thesis: uncompensated -> compensated | thesis reduction "
        "| here: uncompensated | here: best mode | here: reduction |",
        "|---|---|---|---|---|---|",
    ]
    for name, ref in THESIS_RESULTS.items():
        thesis = (
            f"{float(ref['uncompensated_m']) * NM:.1f} -> {float(ref['compensated_m']) * NM:.1f}"
            " nm"
        )
        modes = grouped.get(name, {})
        cut = reductions(modes)
        compensating = {m: c for m, c in cut.items() if m != BASELINE_MODE and math.isfinite(c)}
        base = modes.get(BASELINE_MODE)
        if base is None or not compensating:
            here = ["not run", "-", "-"]
        else:
            best = max(compensating, key=lambda m: compensating[m])
            here = [
                f"{base.metrics.variation_m * NM:.2f} nm",
                f"{best} ({modes[best].metrics.variation_m * NM:.3f} nm)",
                _pct(compensating[best]),
            ]
        lines.append(
            f"| {name} | {thesis} | {_pct(float(ref['reduction']))} | {' | '.join(here)} |"
        )
    return lines


def _invariants_table(runs: Sequence[RunResult]) -> list[str]:
    lines = [
        "| run | commands | max abs V | non-finite | beyond limit | /dm published = recorded "
        "| diagnostics sent before recording | failures |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        inv = r.invariants
        topics = sorted(inv.recorded)
        same = sum(1 for t in topics if inv.published.get(t) == inv.recorded[t])
        early = sum(inv.diagnostics_before_recording.values())
        lines.append(
            f"| {r.scenario} / {r.mode} | {inv.command_count} | {inv.command_max_abs_v:.1f} | "
            f"{inv.command_non_finite} | {inv.command_beyond_limit} | "
            f"{same}/{len(topics)} topics | {early} | {'; '.join(inv.failures) or 'none'} |"
        )
    return lines


def write_report(inputs: ReportInputs, out_dir: Path) -> Path:
    """Write summary.json, report.md and figures into ``out_dir``; return report.md's path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    figures = out_dir / "figures"
    figures.mkdir(exist_ok=True)
    doc = summary(inputs.runs, inputs.bag_dir)
    (out_dir / "summary.json").write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")

    md = ["# es_dm main job: closed-loop scenarios with calibrated feedforward", ""]
    if inputs.command:
        md += [f"Command: `{inputs.command}`; wall time {inputs.wall_s:.0f} s.", ""]
    for paragraph in inputs.preamble:
        md += [paragraph, ""]
    for rel, caption in inputs.extra_figures:
        md += [f"![{caption}]({rel})", "", f"*{caption}*", ""]
    md += ["## Against the thesis", ""]
    md += _thesis_table(inputs.runs)
    md += ["", "## Closed-loop scenarios", ""]
    md += [
        "Variation = the thesis's temperature-induced variation: the output is cut into whole "
        "set-point periods, periods in the same 0.2 degC temperature slot are averaged, and the "
        "largest deviation of any averaged period from the one at the mid-range temperature "
        "is reported (per actuator; a grid reports its worst actuator). AC-only = the same "
        "with each averaged period's mean removed, the thesis's normalisation in section 4-2. "
        "Reduction is against `uncompensated` in the same scenario. Errors are displacement "
        "minus set point over every actuator and sample after the start-up period.",
        "",
    ]
    for name, modes in by_scenario(inputs.runs).items():
        md += [f"### {name}", "", _thesis_line(name), ""]
        md += _results_table(modes)
        first = next(iter(modes.values()))
        md += [
            "",
            f"Simulated {first.sim_s:.0f} s per run; bags: "
            + ", ".join(f"`{r.bag}`" for r in modes.values()),
            "",
        ]
        periods = figures / f"{name}_periods.png"
        errors = figures / f"{name}_error_vs_temperature.png"
        plot_periods(name, modes, periods)
        plot_error_vs_temperature(name, modes, errors)
        md += [f"![{name} periods](figures/{periods.name})", ""]
        md += [f"![{name} error vs temperature](figures/{errors.name})", ""]
        if first.run.output.shape[1] > 1:
            maps = figures / f"{name}_error_map.png"
            plot_error_maps(name, modes, maps)
            md += [f"![{name} error maps](figures/{maps.name})", ""]
    md += ["## Invariants of every run", ""]
    md += [
        "Every value on /dm/command finite and within the amplifier limit; every message a "
        "node published on a /dm topic is in the bag (counts from the nodes' exit logs "
        "against the bag), the recorder wrote everything it received and the middleware "
        "reported no loss. /diagnostics reports a node sends while it starts, before the "
        "recorder has matched it, cannot reach the bag (volatile QoS): they are counted, not "
        "failed.",
        "",
    ]
    md += _invariants_table(inputs.runs)
    md += [""]
    for paragraph in inputs.notes:
        md += [paragraph, ""]
    report = out_dir / "report.md"
    report.write_text("\n".join(md), encoding="utf-8")
    return report
