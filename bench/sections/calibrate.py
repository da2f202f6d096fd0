"""Section ``calibrate``: the calibration tool's wall time (bench_calibrate.py)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from common.benchlib import Context, Record, top_of


def run(context: Context) -> None:
    """Calibration tool wall time on synthetic measured-data bags (1 x 1 and 32 x 32)."""
    from bench_calibrate import bench_calibrate

    settings, results = context.settings, context.results
    for grid, duration, repeats in ((1, settings.calibrate_small_duration, settings.repeats),
                                    (32, settings.calibrate_large_duration, 1)):
        timings = [bench_calibrate(grid, grid, duration, settings.calibrate_rate)
                   for _ in range(repeats)]
        results.records.append(Record.of("calibrate_time", grid * grid,
                                          [t.calibrate_s for t in timings], "s"))
        results.calibrate_durations[grid * grid] = duration
        results.notes.append(
            f"calibrate_time n={grid * grid}: {grid} x {grid} actuators, {duration:g} s of data "
            f"at {settings.calibrate_rate:g} Hz, {repeats} run(s); generating the bag took "
            f"{np.median([t.generate_s for t in timings]):.1f} s (not included)."
        )
        if grid == 32 and settings.profile and np.median([t.calibrate_s for t in timings]) > 60:
            results.profiles["calibration of 32 x 32 x 30 s at 500 Hz"] = _profile_calibration(
                settings.calibrate_rate)


def _profile_calibration(rate: float) -> str:
    """Profile the calibration tool (in this process) on a 32 x 32 bag of 30 s."""
    import cProfile

    from bench_calibrate import write_measured_bag

    from es_calibration.calibrate import run

    with tempfile.TemporaryDirectory(prefix="bench_calibrate_profile_") as tmp:
        bag = Path(tmp) / "bag"
        write_measured_bag(bag, 32, 32, 30.0, rate)
        profile = Path(tmp) / "calibrate.prof"
        profiler = cProfile.Profile()
        profiler.runcall(run, [str(bag), "-o", str(Path(tmp) / "out"), "-q"])
        profiler.dump_stats(profile)
        return top_of(profile, 14)
