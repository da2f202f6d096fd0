"""Section ``scale``: the feedforward node at 66 x 66 / 2 kHz and 128 x 128 / 1 kHz."""

from __future__ import annotations

from common.benchlib import Context


def run(context: Context) -> None:
    """Run :func:`bench_scale.section_scale`."""
    from bench_scale import section_scale

    section_scale(context.settings, context.results, context.log_dir)
