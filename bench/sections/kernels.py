"""Section ``kernels``: each feedforward mode's cost per set point (bench_kernels.py)."""

from __future__ import annotations

import numpy as np
from common.benchlib import Context, Record


def run(context: Context) -> None:
    """Each mode's per-set-point cost and the laws+inverse kernel, against one np.sqrt."""
    from bench_kernels import FLOOR_SUFFIX, bench_kernels

    settings, results = context.settings, context.results
    runs = [bench_kernels(settings.kernel_sizes, repeats=1) for _ in range(settings.repeats)]
    keys = [(row.kernel, row.size) for row in runs[0]]
    for index, (kernel, size) in enumerate(keys):
        rows = [run[index] for run in runs]
        name = "kernel_" + kernel.replace("laws+", "laws_")
        ratio = float(np.median([row.ratio_to_sqrt for row in rows]))
        record = Record.of(name, size, [r.seconds_per_call for r in rows], "s", ratio)
        # a floor is the reference a kernel is read against, not a kernel with a target
        (results.references if kernel.endswith(FLOOR_SUFFIX) else results.records).append(record)
    for size in settings.kernel_sizes:
        floor = [row.sqrt_seconds_per_call for run in runs for row in run if row.size == size]
        results.references.append(Record.of("floor_np_sqrt", size, floor, "s"))
    results.notes.append(
        "kernel_<mode>: Feedforward.command of that mode with the temperature laws already "
        "evaluated (the cost per set point); kernel_laws_inverse_hyperbolic: laws and "
        "hyperbolic inverse together; kernel_update_temperature: laws at a new temperature; "
        "kernel_observer_10hz / _jumps: the observer following a moving set point, and "
        "kernel_observer_*_floor: the numpy SIMD passes its arithmetic needs for the same "
        "updates (sqrt, a tanh per update, a divide per step and for the model error), "
        "nothing else. "
        "kernel_discovered_<none|output|drive>_10hz: the hyperbolic inverse following a "
        "10 Hz sine at 2 kHz without a discovered term, with an output-side one and with a "
        "drive-side one (the fixed-point inverse of the augmented law). "
        "ratio = time / one np.sqrt over the same N, measured alternately in the same run."
    )
