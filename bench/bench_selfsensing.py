"""Self-sensing goal run: temperature error and feedforward variation, three sensor set-ups.

Usage (from the repository root, after ./scripts/bootstrap)::

    .venv/bin/python bench/bench_selfsensing.py [--pitch 6] [--duration S]

Offline, pure cores (no DDS), :mod:`es_bringup.selfsensing_study`: the resonance laws are
calibrated from the ``characterisation`` test-stand scenario run offline with the sweeps on;
then ``dm_exposure`` (12 x 12, dipole exposure: a non-uniform heat load) runs in closed loop
with (a) 4 NTCs (one per 6 x 6 block) and the thermal model, (b) the same plus
self-sensing, (c) an NTC on every actuator. :func:`selfsensing_figures` returns the figures
and the goal checks of issue 20; ``main`` prints them as JSON.
"""

from __future__ import annotations

import argparse
import json
import time

from es_bringup.selfsensing_study import CASES, characterise, study

#: Issue-20 goals for case (b): RMS, worst actuator [degC], improvement over (a), variation
#: ratio to (c).
GOAL_RMS, GOAL_WORST, GOAL_GAIN, GOAL_VARIATION_RATIO = 0.02, 0.05, 5.0, 1.2


def selfsensing_figures(pitch: int = 6, duration: float | None = None) -> dict[str, float]:
    """Run the calibration and the three cases; return the figures [degC, m, s].

    Keys per case c of :data:`CASES`: ``selfsensing_rms_<c>``, ``selfsensing_worst_<c>``,
    ``selfsensing_max_<c>`` (degC), ``selfsensing_variation_<c>`` (m); and
    ``selfsensing_gain`` (RMS (a) / (b)), ``selfsensing_variation_ratio`` ((b) / (c)),
    ``selfsensing_calibration_s`` and ``selfsensing_study_s`` (wall time).
    """
    started = time.perf_counter()
    fit = characterise()
    calibrated = time.perf_counter()
    cases = study(pitch=pitch, duration=duration, fit=fit)
    done = time.perf_counter()
    out: dict[str, float] = {}
    for name in CASES:
        c = cases[name]
        out[f"selfsensing_rms_{name}"] = c.rms
        out[f"selfsensing_worst_{name}"] = c.worst
        out[f"selfsensing_max_{name}"] = c.max_error
        out[f"selfsensing_variation_{name}"] = c.variation_m
    out["selfsensing_gain"] = cases["ntc"].rms / cases["ntc_selfsensing"].rms
    out["selfsensing_variation_ratio"] = (
        cases["ntc_selfsensing"].variation_m / cases["sensor_per_actuator"].variation_m
    )
    out["selfsensing_calibration_s"] = calibrated - started
    out["selfsensing_study_s"] = done - calibrated
    return out


def goal_checks(f: dict[str, float]) -> list[str]:
    """Return one line per issue-20 goal: the measured figure, the target, met or not."""
    b = "ntc_selfsensing"
    checks = [
        ("RMS error (b)", f[f"selfsensing_rms_{b}"], "<=", GOAL_RMS, "degC"),
        ("worst actuator (b)", f[f"selfsensing_worst_{b}"], "<=", GOAL_WORST, "degC"),
        ("RMS (a) / RMS (b)", f["selfsensing_gain"], ">=", GOAL_GAIN, "x"),
        ("variation (b) / (c)", f["selfsensing_variation_ratio"], "<=", GOAL_VARIATION_RATIO, "x"),
    ]
    lines = []
    for name, value, op, target, unit in checks:
        met = value <= target if op == "<=" else value >= target
        verdict = "met" if met else "NOT met"
        lines.append(f"{name}: {value:.3g} {unit} (goal {op} {target:g}) {verdict}")
    return lines


def main() -> None:
    """Print the figures of one run as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pitch", type=int, default=6)
    parser.add_argument("--duration", type=float, default=None, help="sim s (default: scenario)")
    args = parser.parse_args()
    figures = selfsensing_figures(args.pitch, args.duration)
    print(json.dumps({"figures": figures, "goals": goal_checks(figures)}, indent=2))


if __name__ == "__main__":
    main()
