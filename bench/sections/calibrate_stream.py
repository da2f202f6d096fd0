"""Section ``calibrate_stream``: streamed calibration of 64 x 64 and 128 x 128 bags (many GB)."""

from __future__ import annotations

from common.benchlib import Context


def run(context: Context) -> None:
    """Run :func:`bench_calibrate_stream.section_calibrate_stream`."""
    from bench_calibrate_stream import section_calibrate_stream

    section_calibrate_stream(context.settings, context.results)
