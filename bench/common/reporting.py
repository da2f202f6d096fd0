"""The benchmark's report files: ``bench.json``, ``bench.md`` and ``summary.md``.

The targets of the performance issue are checked against the records here.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from common.benchlib import Record, Results, Settings

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


#: Figures of the compact table (summary.md, docs/benchmarks.md): (name prefix, sizes; empty =
#: every size).
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


def summary_header(machine: dict[str, Any], date: str) -> list[str]:
    """Return the lines above a summary table: when and where, then the table's head."""
    return [
        f"Measured {date} on {machine['cores']} cores, {machine['cpu_model']} (load average "
        f"{machine['load_average_at_start'][0]} at the start: a shared machine); median "
        "(min-max) of repeated runs.", "",
        "| figure | n | median (min-max) | unit | ratio |", "|---|---:|---|---|---:|",
    ]


def summary_row(r: Record) -> str:
    """Return one figure's row of a summary table (sub-10 ms times in us)."""
    scale, unit = (1e6, "us") if r.unit == "s" and r.median < 0.01 else (1.0, r.unit)
    spread = f"{_fmt(r.median * scale)} ({_fmt(r.min * scale)}-{_fmt(r.max * scale)})"
    return f"| {r.name} | {r.n} | {spread} | {unit} | {_fmt(r.ratio)} |"


def summary_lines(results: Results, machine: dict[str, Any], date: str) -> list[str]:
    """Return summary.md's lines: the compact table of the main figures and the targets."""
    lines = summary_header(machine, date)
    for prefix, sizes in SUMMARY_ROWS:
        for r in results.records:
            if r.name.startswith(prefix) and (not sizes or r.n in sizes):
                lines.append(summary_row(r))
    lines += ["", "Targets (issue 9):", "", *[f"- {t}" for t in check_targets(results)], ""]
    return lines


def write_summary(out: Path, results: Results, machine: dict[str, Any], date: str) -> None:
    """Write summary.md: the compact table docs/benchmarks.md shows (full tables in bench.md)."""
    (out / "summary.md").write_text("\n".join(summary_lines(results, machine, date)))
