"""Section ``selfsensing``: temperature error with and without self-sensing (offline)."""

from __future__ import annotations

from common.benchlib import Context, Record


def run(context: Context) -> None:
    """Issue 20: temperature error and variation with 4 NTCs, + self-sensing, NTC each."""
    from bench_selfsensing import goal_checks, selfsensing_figures

    from es_bringup.selfsensing_study import CASES

    results = context.results
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
