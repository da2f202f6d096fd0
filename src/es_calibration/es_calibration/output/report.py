"""Markdown report and PNG figures of a calibration (matplotlib, Agg backend, no display)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from es_calibration.data.align import AlignedData
from es_calibration.data.gaps import COMMAND_SETTLING_S, GAP_FACTOR
from es_calibration.discovery.standins import STEP as STAND_IN_STEP
from es_calibration.output.discovered_report import discovery_lines
from es_calibration.output.schema import law_uncertainty
from es_calibration.pipeline import NOISE_RATIO_LIMIT, Calibration
from es_calibration.search.residual import ResidualStructure
from es_physics.params import THESIS_INTERVALS_95

NM = 1e9


def _fmt(value: float) -> str:
    return f"{value:.4g}"


def _figure_time(cal: Calibration, out: Path) -> str:
    t, before = cal.analysis_before
    _, after = cal.analysis_after
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(t, before[0] * NM, ".", ms=1.5, label="basic law")
    ax.plot(t, after[0] * NM, ".", ms=1.5, label="with accepted effects")
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel("held-out residual [nm]")
    ax.set_title("Held-out residual of actuator 0 (held-out blocks only)")
    ax.legend(markerscale=6)
    fig.tight_layout()
    fig.savefig(out / "residual_time.png", dpi=90)
    plt.close(fig)
    return "residual_time.png"


def _figure_dependence(cal: Calibration, out: Path) -> str:
    deps = list(zip(cal.before.dependences, cal.after.dependences, strict=True))
    fig, axes = plt.subplots(1, len(deps), figsize=(3.2 * len(deps), 3.2), squeeze=False)
    for ax, (b, a) in zip(axes[0], deps, strict=True):
        for d, label in ((b, "basic law"), (a, "with effects")):
            ax.errorbar(
                d.centers, d.mean * NM, yerr=d.bound * NM, fmt="o-", ms=3, capsize=2, label=label
            )
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel(f"{b.name} [{b.unit}]")
        ax.set_title(f"r = {b.correlation:+.2f} -> {a.correlation:+.2f}", fontsize=9)
    axes[0][0].set_ylabel("mean residual (95 % bound) [nm]")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "residual_vs_inputs.png", dpi=90)
    plt.close(fig)
    return "residual_vs_inputs.png"


def _figure_spectrum(cal: Calibration, out: Path) -> str:
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for s, label in ((cal.before, "basic law"), (cal.after, "with accepted effects")):
        ax.semilogy(s.frequencies[1:], np.sqrt(s.psd[1:]) * NM, label=label)
    rate = cal.aligned.sample_rate
    floor = cal.noise_floor_m
    if np.isfinite(floor) and floor > 0:
        ax.axhline(
            floor * NM / np.sqrt(rate / 2.0),
            color="k",
            ls="--",
            lw=0.8,
            label="white noise at the noise floor",
        )
    for f, _ in cal.after.lines:
        ax.axvline(f, color="r", lw=0.5, alpha=0.6)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("residual ASD [nm/sqrt(Hz)]")
    ax.set_title("Held-out residual spectrum (red: unexplained lines)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "residual_spectrum.png", dpi=90)
    plt.close(fig)
    return "residual_spectrum.png"


def _figure_correlation(cal: Calibration, out: Path) -> str:
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.6))
    for s, label in ((cal.before, "basic law"), (cal.after, "with accepted effects")):
        ax1.plot(s.lags_s, s.autocorrelation, label=label)
    bound = cal.after.autocorrelation_bound
    ax1.axhspan(-bound, bound, color="0.8", label="95 % bound (white)")
    ax1.set_xlabel("lag [s]")
    ax1.set_ylabel("autocorrelation")
    ax1.legend(fontsize=8)
    names = [d.name for d in cal.before.dependences]
    x = np.arange(len(names))
    ax2.bar(x - 0.2, [d.correlation for d in cal.before.dependences], 0.4, label="basic law")
    ax2.bar(x + 0.2, [d.correlation for d in cal.after.dependences], 0.4, label="with effects")
    for i, d in enumerate(cal.after.dependences):
        ax2.plot([i - 0.45, i + 0.45], [d.correlation_bound] * 2, "k--", lw=0.8)
        ax2.plot([i - 0.45, i + 0.45], [-d.correlation_bound] * 2, "k--", lw=0.8)
    ax2.set_xticks(x, names)
    ax2.set_ylabel("correlation with residual (dashed: 95 % bound)")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "residual_correlation.png", dpi=90)
    plt.close(fig)
    return "residual_correlation.png"


def _structure_lines(s: ResidualStructure) -> list[str]:
    lines = [
        f"- RMS {_fmt(s.rms * NM)} nm, max |residual| {_fmt(s.max_abs * NM)} nm over "
        f"{s.count} samples; noise floor {_fmt(s.noise_floor * NM)} nm; integrated "
        f"autocorrelation time {s.tau_int:.1f} samples",
    ]
    for d in s.dependences:
        flag = "significant" if abs(d.correlation) > d.correlation_bound else "not significant"
        lines.append(
            f"- vs {d.name}: r = {d.correlation:+.3f} (95 % bound {d.correlation_bound:.3f}, "
            f"{flag}); binned means explain {100 * d.explained_fraction:.1f} % of the variance"
        )
    if s.lines:
        lines.append(
            "- spectral lines: "
            + ", ".join(f"{f:.3g} Hz ({_fmt(a * NM)} nm rms)" for f, a in s.lines)
        )
    else:
        lines.append("- no spectral line stands out of the local spectral level")
    return lines


def _gap_lines(a: AlignedData) -> list[str]:
    """Return the report's lines on gaps in the measured topics (rules: gaps.py)."""
    if not a.gaps:
        return [f"- no gap (no interval > {GAP_FACTOR:g} x a topic's median period)"]
    lines = [
        f"- {len(a.gaps)} gap(s), intervals > {GAP_FACTOR:g} x the topic's median period; the "
        "samples that would need data from a gap are left out of fit and scoring (a command "
        f"hole also takes {COMMAND_SETTLING_S:g} s after it, a temperature gap the half-window "
        "of dT/dt on each side):",
        "",
        "| topic | start (bag time) [s] | start (since first sample) [s] | length [s] | "
        "missing messages | excluded samples |",
        "|---|---|---|---|---|---|",
    ]
    lines += [
        f"| `{g.topic}` | {g.start_s:.3f} | {g.start_s - a.start_time:.3f} | "
        f"{g.duration_s:.3f} | {g.missing_samples} | {g.excluded_samples} |"
        for g in a.gaps
    ]
    return [*lines, ""]


def _edge_lines(a: AlignedData) -> list[str]:
    """Return the report's line on unresolvable command edges (rule: edges.py)."""
    e = a.command_edges
    if e is None:
        return []
    if not e.edges:
        return ["- no unresolvable command edge (every command interval is smooth enough to "
                "interpolate)"]
    examples = ", ".join(f"{x - a.start_time:.3f}" for x in e.example_times_s)
    more = ", ..." if e.edges > len(e.example_times_s) else ""
    per = np.asarray(e.per_actuator_edges)
    return [
        f"- {e.edges} command interval(s) with an edge the command samples cannot resolve "
        f"(e.g. at {examples}{more} s since the first sample), {e.pairs} edge(s) of single "
        f"actuators' commands ({per.min()}-{per.max()} per actuator); an edge takes out only "
        f"the samples of the actuators whose command has it: {e.excluded_pairs} "
        f"(sample, actuator) pairs ({100 * e.fraction:.2f} %) whose input could read one at "
        f"the delay found ({e.before_s * 1e3:.3g} ms before to {e.after_s * 1e3:.3g} ms "
        "after it) are left out of fit and scoring",
        "",
    ]


def _span_lines(a: AlignedData) -> list[str]:
    """Return the report's line on samples outside the temperature topic (rule: gaps.py)."""
    s = a.temperature_span
    if s is None or not s.excluded_samples:
        return []
    return [
        f"- {s.excluded_before} displacement samples before the first temperature message "
        f"(bag time {s.start_s:.3f} s) and {s.excluded_after} after the last "
        f"({s.end_s:.3f} s) are left out of fit and scoring "
        "(their temperature would be extrapolated)",
    ]


def _law_table(cal: Calibration) -> list[str]:
    local = cal.final.fit.local
    sig = law_uncertainty(cal)
    rows = [
        "| coefficient | median | min | max | median 1-sigma | thesis 95 % interval |",
        "|---|---|---|---|---|---|",
    ]
    for i, name in enumerate(cal.final.model.local_names):
        if name in cal.final.model.per_actuator:
            continue  # an effect's parameter (section e), not the law's
        v = local[:, i]
        interval = THESIS_INTERVALS_95.get(name)
        thesis = f"{interval[0]:.4g} .. {interval[1]:.4g}" if interval else "-"
        rows.append(
            f"| {name} | {_fmt(float(np.median(v)))} | {_fmt(float(v.min()))} | "
            f"{_fmt(float(v.max()))} | {_fmt(float(np.median(sig[name])))} | {thesis} |"
        )
    return rows


def _health_lines(cal: Calibration) -> list[str]:
    """Return the verdict and the recording health section (before the physics)."""
    v = cal.verdict
    lines = [f"**Verdict: {v.level}**" + (": " + "; ".join(v.reasons) if v.reasons else ""),
             "", "## Recording health", "",
             f"Kept for the fit: {100 * cal.kept_fraction:.1f} % of the screening block's "
             "(sample, actuator) pairs"
             + ("" if cal.grid_kept_fraction is None else
                f", at least {100 * cal.grid_kept_fraction:.1f} % of the whole grid's "
                "(each actuator's own command edges)")
             + "; displacement clock against the command's: "
             + ("not estimated" if cal.clock_rate_ppm is None
                else f"{cal.clock_rate_ppm:+.3g} ppm") + ".", ""]
    if not cal.findings:
        return [*lines, "No fault of the recording or of an actuator found.", ""]
    lines += ["| kind | subject | time [s] | value | what it is | action |",
              "|---|---|---|---|---|---|"]
    for f in cal.findings:
        value = "-" if f.value is None else f"{_fmt(f.value)} {f.unit}"
        lines.append(f"| {f.kind} | {f.subject} | {f.start_s:.1f}-{f.end_s:.1f} | {value} "
                     f"| {f.sentence} | {f.action} |")
    return [*lines, ""]


def write_report(cal: Calibration, out: Path, notes: list[str]) -> Path:
    """Write report.md and its figures into ``out``; return the report's path."""
    a = cal.aligned
    figs = {
        "time": _figure_time(cal, out),
        "dep": _figure_dependence(cal, out),
        "spec": _figure_spectrum(cal, out),
        "corr": _figure_correlation(cal, out),
    }
    floor = cal.noise_floor_m
    ratio = cal.final.heldout_rms / floor if floor > 0 else float("nan")
    text: list[str] = [
        "# Calibration report",
        "",
        f"Held-out RMS error: **{_fmt(cal.base.heldout_rms * NM)} nm** with the basic law, "
        f"**{_fmt(cal.final.heldout_rms * NM)} nm** with "
        + (", ".join(e.name for e in cal.effects) if cal.effects else "no added effect")
        + f"; measurement noise floor {_fmt(floor * NM)} nm (ratio {ratio:.2f}, goal <= "
        f"{NOISE_RATIO_LIMIT}).",
        "",
        *_health_lines(cal),
        "## a. Data and alignment",
        "",
        f"- grid {a.grid[0]} x {a.grid[1]}, {a.t.size} displacement samples over "
        f"{a.t[-1]:.1f} s ({a.sample_rate:.4g} Hz), command period {a.command_period:.4g} s, "
        f"temperature from `{a.temperature_source}` (resampled at "
        f"{1.0 / np.median(np.diff(a.temperature_times)):.4g} Hz, linearly interpolated "
        "between messages, never across a gap)",
        "- command in effect at a sample: the last one stamped "
        + ("at or before" if a.include_same_stamp else "strictly before")
        + " it (decided from the data)",
        f"- {a.block_edges.size - 1} interleaved blocks of {a.block_edges[1]:.2f} s: "
        f"{int(a.train.sum())} training and {int((~a.train).sum())} held-out samples",
        "- dropped values: " + (", ".join(f"{k}: {v}" for k, v in a.dropped.items()) or "none"),
        "- effect search on " + (cal.search_span or "the whole record"),
        *([f"- {a.repeated_stamps}"] if a.repeated_stamps else []),
        *_gap_lines(a),
        *_span_lines(a),
        *_edge_lines(a),
        "",
        "## b. Law fit (hyperbolic, M and k "
        + ("quadratic" if cal.final.model.law is not None else "linear")
        + " in T* = T - Tm, L and Tm fixed)",
        "",
        *_law_table(cal),
        "",
        "Uncertainties are 1-sigma from the Gauss-Newton covariance, inflated by the residual's "
        "integrated autocorrelation time.",
        "",
        "## c. Held-out residual of the basic law",
        "",
        *_structure_lines(cal.before),
        "",
        f"![residual vs time]({figs['time']})",
        "",
        f"![residual vs inputs]({figs['dep']})",
        "",
        f"![spectrum]({figs['spec']})",
        "",
        f"![correlations]({figs['corr']})",
        "",
        "## d. Candidate effects",
        "",
        "Each candidate is refitted jointly with the law on training blocks and scored on "
        "held-out blocks (BIC with the effective number of independent residuals; an accepted "
        "effect must also cut the held-out RMS by >= 1 % with physical parameter values). "
        "With two or more effects accepted, a backward check takes each out again and drops "
        "those the same criterion no longer needs.",
        "",
    ]
    for i, rnd in enumerate(cal.rounds, 1):
        if rnd.step in ("backward", STAND_IN_STEP):
            title = f"removed **{rnd.removed}**" if rnd.removed else "every effect still needed"
            check = ("backward check" if rnd.step == "backward"
                     else "stand-in check with the discovered terms")
            text += [
                f"Round {i}, {check}: {title}",
                "",
                "| effect | RMS without [nm] | RMS with [nm] | dBIC | verdict | parameters |",
                "|---|---|---|---|---|---|",
            ]
        else:
            title = f"added **{rnd.added}**" if rnd.added else "nothing added"
            text += [
                f"Round {i}: {title}",
                "",
                "| candidate | RMS before [nm] | RMS after [nm] | dBIC | verdict | parameters |",
                "|---|---|---|---|---|---|",
            ]
        for s in rnd.scores:
            params = ", ".join(f"{k} = {_fmt(v)}" for k, v in s.parameters.items())
            verdict = (
                s.reason if rnd.step in ("backward", STAND_IN_STEP)
                else ("accepted" if s.accepted else s.reason)
            )
            text.append(
                f"| {s.name} | {_fmt(s.rms_before_m * NM)} | {_fmt(s.rms_after_m * NM)} "
                f"| {s.delta_ic:+.1f} | {verdict} | {params} |"
            )
        text.append("")
    text += ["## e. Accepted effects and what remains", ""]
    if cal.effects:
        text += [
            "| effect | parameters (1-sigma) | held-out RMS before -> after [nm] | "
            "share of the error removed | after / noise floor |",
            "|---|---|---|---|---|",
        ]
        for e in cal.effects:
            params = ", ".join(
                f"{k} = {_fmt(v)}"
                + (f" +- {_fmt(e.uncertainties[k])}" if k in e.uncertainties else "")
                + (
                    f" (grid median; per actuator {_fmt(min(e.per_actuator[k]))} .. "
                    f"{_fmt(max(e.per_actuator[k]))})"
                    if k in e.per_actuator
                    else ""
                )
                for k, v in e.parameters.items()
            )
            off = "" if e.enabled else " (not confirmed on the record's halves: written off)"
            text.append(
                f"| {e.name}{off} | {params} | {_fmt(e.rms_before_m * NM)} -> "
                f"{_fmt(e.rms_after_m * NM)} | {100 * e.share:.0f} % | "
                f"{e.rms_after_m / floor:.2f} |"
            )
    else:
        text.append("No candidate passed: the basic law is kept.")
    text += [
        "",
        "Residual with the final model:",
        "",
        *_structure_lines(cal.after),
        "",
        "Unexplained structure:",
        "",
    ]
    text += [f"- {u}" for u in cal.unexplained] or ["- none beyond the measurement noise"]
    text += ["", *discovery_lines(cal.discovery, cal.base.heldout_rms, floor)]
    if notes:
        text += ["", "Parameter file notes:", "", *[f"- {n}" for n in notes]]
    text += [
        "",
        "## Outputs",
        "",
        "- `calibration.json` (schema: es_calibration.output.schema)",
        "- `feedforward_params.yaml` (load with `--ros-args --params-file`)",
        "",
        "Timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in cal.timings_s.items()),
        "",
    ]
    path = out / "report.md"
    path.write_text("\n".join(text), encoding="utf-8")
    return path
