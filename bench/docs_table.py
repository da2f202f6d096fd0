"""Rewrite the table of measured figures in a docs page from a benchmark run's bench.json.

Usage (from the repository root)::

    .venv/bin/python bench/docs_table.py out/bench-<time>/bench.json docs/benchmarks.md

The page marks the table with the lines ``<!-- bench-table:begin -->`` and
``<!-- bench-table:end -->``; what lies between is replaced by the run's summary (the table
of ``summary.md``: :func:`common.reporting.summary_lines`) and the command that measured it,
so the figures in the docs are the benchmark's own output, never copied by hand. A missing or
unreadable file, or a page without the two markers, ends with one line on stderr and exit
status 2; the page is then left as it was.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from common.benchlib import Record, Results
from common.reporting import summary_lines

BEGIN = "<!-- bench-table:begin -->"
END = "<!-- bench-table:end -->"


def table_block(bench: dict) -> list[str]:
    """Return the lines that go between the markers for one run's bench.json contents.

    Raises:
        KeyError: a field of bench.json is missing.
        TypeError: a record has other fields than a :class:`Record`.

    """
    results = Results(records=[Record(**r) for r in bench["records"]])
    lines = summary_lines(results, bench["machine"], bench["date"])
    return [*lines, f"Command: `{bench['command']}`.", ""]


def rewrite(page: str, block: list[str]) -> str:
    """Return ``page`` with the text between the markers replaced by ``block``.

    Raises:
        ValueError: the page lacks a marker, or has them out of order.

    """
    lines = page.splitlines()
    if lines.count(BEGIN) != 1 or lines.count(END) != 1 or lines.index(BEGIN) > lines.index(END):
        raise ValueError(f"the page needs one {BEGIN} line followed by one {END} line")
    start, stop = lines.index(BEGIN), lines.index(END)
    return "\n".join([*lines[: start + 1], *block, *lines[stop:]]) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Rewrite the page's table; 0 on success, 2 with one line on stderr otherwise."""
    parser = argparse.ArgumentParser(prog="docs_table", description=__doc__.splitlines()[0])
    parser.add_argument("bench_json", type=Path, help="bench.json of a ./scripts/bench run")
    parser.add_argument("page", type=Path, help="the docs page with the two markers")
    args = parser.parse_args(argv)
    try:
        block = table_block(json.loads(args.bench_json.read_text()))
        args.page.write_text(rewrite(args.page.read_text(), block))
    except (OSError, ValueError, KeyError, TypeError) as err:
        print(f"docs_table: {err}", file=sys.stderr)
        return 2
    print(f"docs_table: {args.page} now shows {args.bench_json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
