"""Section ``lockstep_scale``: the closed loop at 32 x 32 and 64 x 64."""

from __future__ import annotations

from common.benchlib import Context


def run(context: Context) -> None:
    """Run :func:`bench_lockstep_scale.section_lockstep_scale`."""
    from bench_lockstep_scale import section_lockstep_scale

    section_lockstep_scale(context.settings, context.results, context.log_dir)
