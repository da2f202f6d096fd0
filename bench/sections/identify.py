"""Section ``identify``: the identification sweep (standgen.identify) on standgen bags."""

from __future__ import annotations

import datetime as dt
import os
import time

from common.benchlib import Context, Record


def run(context: Context) -> None:
    """Run the identification sweep (standgen.identify): right effect sets, clean FP rate, RMS."""
    from standgen import identify

    quick, results, out = context.quick, context.results, context.out / "identify"
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
                      ("identify_right_within_1p2_noise", "right_within_1p2_true_noise"),
                      ("identify_fault_named", "fault_named"),
                      ("identify_fault_law_within_5pct", "fault_law_within_5pct"),
                      ("identify_unlisted_within_1p3_noise", "unlisted_within_1p3")):
        if summary[key] is not None:
            results.records.append(Record.of(name, n, [summary[key]], "fraction"))
    for name, key in (("identify_fault_stand_ins", "fault_stand_ins"),
                      ("identify_unlisted_stand_ins", "unlisted_stand_ins"),
                      ("identify_clean_discovered", "clean_discovered")):
        results.records.append(Record.of(name, n, [float(summary[key])], "cases"))
    results.records.append(Record.of("identify_wall_time", n, [wall], "s"))
    results.notes.append(f"identify_*: {n} standgen cases ({'quick' if quick else 'full'}), "
                         f"{jobs} jobs; goals: {'; '.join(identify.goal_lines(summary))}; "
                         f"tables in {out / 'identify.md'}.")
