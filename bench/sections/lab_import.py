"""Section ``import``: lab recordings into bags, time and peak memory (bench_import.py)."""

from __future__ import annotations

from common.benchlib import Context, Record


def run(context: Context) -> None:
    """Import of lab recordings (issue 19): time and peak memory per format, one run each."""
    from bench_import import describe, run_cases

    quick, results = context.quick, context.results
    for t in run_cases(quick):
        n = t.rows * t.cols
        results.records.append(Record.of(f"import_time_{t.fmt}_{t.samples}", n, [t.seconds], "s"))
        results.records.append(Record.of(f"import_mem_{t.fmt}_{t.samples}", n, [t.import_mib],
                                         "MiB"))
        results.notes.append(f"import: {describe(t)}")
