"""Section ``multihost``: 64 x 64 at 1 kHz across two network namespaces (root)."""

from __future__ import annotations

from common.benchlib import Context


def run(context: Context) -> None:
    """Run :func:`bench_multihost.section_multihost`."""
    from bench_multihost import section_multihost

    section_multihost(context.settings, context.results, context.log_dir)
