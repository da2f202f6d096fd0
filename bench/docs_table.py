"""Rewrite the table of measured figures in a docs page from a benchmark run's bench.json.

Usage (from the repository root)::

    .venv/bin/python bench/docs_table.py out/bench-<time>/bench.json docs/benchmarks.md
    .venv/bin/python bench/docs_table.py docs/bench/teardown.json docs/reliability.md \
        --figures teardown

The page marks the table with the lines ``<!-- bench-table:begin -->`` and
``<!-- bench-table:end -->``; what lies between is replaced by the run's summary (the table
of ``summary.md``: :func:`common.reporting.summary_lines`) or, with ``--figures``, every
figure, note and failure whose name starts with one of the given prefixes; then the command
that measured it and the command that regenerates the block. An identification sweep's
``identify.json`` (``scripts/identify``) gives its goals and its fault and unlisted tables
instead; ``--keep PATH`` also writes the run's settings, summary and goals (not its cases,
to keep committed data small) to PATH, which the regenerating command then reads. So the
figures in the docs are
the benchmark's own output, never copied by hand (tests/install/test_docs_tables.py reruns
that command). A missing or unreadable file, or a page without the two markers, ends with
one line on stderr and exit status 2; the page is then left as it was.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from common.benchlib import Record, Results
from common.reporting import summary_header, summary_lines, summary_row
from standgen.identify import fault_lines, goal_lines, unlisted_lines

BEGIN = "<!-- bench-table:begin -->"
END = "<!-- bench-table:end -->"


def table_block(bench: dict, figures: Sequence[str] = (), regenerate: str = "") -> list[str]:
    """Return the lines that go between the markers for one run's bench.json contents.

    Args:
        bench: the run's bench.json contents.
        figures: prefixes of the figures the block shows (``teardown``, ``lockstep_``), with
            the notes and failures that start with them (less a trailing ``_``); none: the
            run's summary with the issue 9 targets.
        regenerate: the command that rewrites the block, shown under it.

    Raises:
        KeyError: a field of bench.json is missing.
        TypeError: a record has other fields than a :class:`Record`.

    """
    records = [Record(**r) for r in bench["records"]]
    if not figures:
        lines = summary_lines(Results(records=records), bench["machine"], bench["date"])
    else:
        mine = tuple(p.rstrip("_") for p in figures)
        lines = [
            *summary_header(bench["machine"], bench["date"]),
            *[summary_row(r) for r in records if r.name.startswith(tuple(figures))],
            "",
            *[f"- {note}" for note in bench["notes"] if note.startswith(mine)],
            *[f"- not measured: {why}" for why in bench["failures"] if why.startswith(mine)],
            "",
        ]
    lines.append(f"Command: `{bench['command']}`.")
    if regenerate:
        lines.append(f"Regenerate: `{regenerate}`.")
    return [*lines, ""]


def sweep_block(identify: dict, regenerate: str = "") -> list[str]:
    """Return the lines that go between the markers for an identification sweep's results.

    Args:
        identify: identify.json's contents (``settings``, ``summary``; ``cases`` unused).
        regenerate: the command that rewrites the block, shown under it.

    Raises:
        KeyError: a field of identify.json is missing.

    """
    settings, summary = identify["settings"], identify["summary"]
    done, total = settings.get("cases_done"), settings.get("cases_total")
    load = settings.get("load_average")
    lines = [
        f"Measured {settings['date']} on {settings['cores']} cores, {settings['jobs']} case(s) at "
        f"a time, {settings['wall_s']:.0f} s wall"
        + (f" (1-min load average {load:.1f} at the end)" if load is not None else "")
        + f": {summary['cases']} cases, {summary['failed']} calibrations failed"
        + (f", PARTIAL: {done} of {total} cases" if total and done is not None and done < total
           else "") + ".",
        "",
        *[f"- {line}" for line in goal_lines(summary)],
        "",
        *[line.replace("## ", "**", 1) + "**" if line.startswith("## ") else line
          for line in (*fault_lines(summary), *unlisted_lines(summary))],
        f"Command: `{settings['command']}`.",
    ]
    if regenerate:
        lines.append(f"Regenerate: `{regenerate}`.")
    return [*lines, ""]


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
    parser.add_argument("bench_json", type=Path,
                        help="bench.json of a ./scripts/bench run, or identify.json of a sweep")
    parser.add_argument("page", type=Path, help="the docs page with the two markers")
    parser.add_argument("--figures", nargs="+", default=[], metavar="PREFIX",
                        help="show the figures, notes and failures starting with these prefixes "
                        "instead of the run's summary")
    parser.add_argument("--keep", type=Path, metavar="PATH",
                        help="(a sweep) also write its settings, summary and goals to PATH, and "
                        "regenerate from there")
    args = parser.parse_args(argv)
    options = ["--figures", *args.figures] if args.figures else []
    source = args.keep or args.bench_json
    regenerate = " ".join(
        [".venv/bin/python bench/docs_table.py", str(source), str(args.page), *options]
    )
    try:
        document = json.loads(args.bench_json.read_text())
        sweep = "summary" in document  # an identification sweep's identify.json
        if sweep:
            block = sweep_block(document, regenerate)
        else:
            block = table_block(document, args.figures, regenerate)
        page = rewrite(args.page.read_text(), block)
        if sweep and args.keep:
            kept = {key: document[key] for key in ("settings", "summary", "goals")}
            args.keep.write_text(json.dumps(kept, indent=1) + "\n")
        args.page.write_text(page)
    except (OSError, ValueError, KeyError, TypeError) as err:
        print(f"docs_table: {err}", file=sys.stderr)
        return 2
    print(f"docs_table: {args.page} now shows {args.bench_json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
