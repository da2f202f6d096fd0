"""Section ``unlisted_loop``: closed loop on the independent stand with an unlisted effect."""

from __future__ import annotations

import tempfile
from pathlib import Path

from common.benchlib import Context


def run(context: Context) -> None:
    """Characterise, calibrate and close the loop per unlisted family; error per way."""
    from bench_unlisted_loop import FAMILIES, markdown, run_family, write_outputs

    with tempfile.TemporaryDirectory(prefix="bench_unlisted_loop_") as tmp:
        results = [run_family(family, Path(tmp)) for family in (None, *FAMILIES)]
    path = write_outputs(results, context.out)
    context.results.notes.append(f"unlisted_loop: table in {path.name}; " + markdown(results)[0])
