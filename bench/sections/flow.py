"""Section ``flow``: set points paced on the feedforward's acknowledgements (bench_flow.py)."""

from __future__ import annotations

from common.benchlib import Context


def run(context: Context) -> None:
    """Run :func:`bench_flow.section_flow`."""
    from bench_flow import section_flow

    section_flow(context.settings, context.results, context.log_dir)
