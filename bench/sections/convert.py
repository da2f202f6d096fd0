"""Section ``convert``: numpy <-> Float64MultiArray against a copy (bench_convert.py)."""

from __future__ import annotations

import numpy as np
from common.benchlib import Context, Record


def run(context: Context) -> None:
    """Numpy <-> Float64MultiArray for the kernel sizes, against a plain copy."""
    from bench_convert import bench_conversion

    settings, results = context.settings, context.results
    runs = [bench_conversion(settings.kernel_sizes, repeats=5, number=500)
            for _ in range(settings.repeats)]
    for index, size in enumerate(settings.kernel_sizes):
        rows = [run[index] for run in runs]
        memcpy = [row.memcpy_us * 1e-6 for row in rows]
        floor = float(np.median(memcpy))
        to_msg = [row.to_msg_us * 1e-6 for row in rows]
        from_msg = [row.from_msg_us * 1e-6 for row in rows]
        results.records.append(Record.of("convert_to_msg", size, to_msg, "s",
                                          float(np.median(to_msg)) / floor))
        results.records.append(Record.of("convert_from_msg", size, from_msg, "s",
                                          float(np.median(from_msg)) / floor))
        results.references.append(Record.of("floor_copyto", size, memcpy, "s"))
    results.notes.append("convert_*: ratio = time / one np.copyto of the same array.")
