"""Section ``calibration_loop``: characterise, calibrate, closed loop per effect family."""

from __future__ import annotations

import tempfile
from pathlib import Path

from common.benchlib import Context


def run(context: Context) -> None:
    """Run the calibration loop per effect family; closed-loop error against no effect."""
    from bench_calibration_loop import loop_table, markdown, write_outputs

    results, out = context.results, context.out
    with tempfile.TemporaryDirectory(prefix="bench_calibration_loop_") as tmp:
        loops = loop_table(Path(tmp))
    path = write_outputs(loops, out)
    results.notes.append(f"calibration_loop: table in {path.name}; " + markdown(loops)[0])
