"""``import``: turn a lab recording (MATLAB, HDF5, CSV/TSV, NumPy) into a contract bag.

Usage::

    ros2 run es_recordings import REC.mat -o BAG --map MAP.yaml [--storage sqlite3]
    ros2 run es_recordings import --inspect REC.mat      # variables and a guessed map

(console script ``es_recordings-import``). The map is described in
:mod:`es_recordings.labimport.mapfile`. On success a summary goes to stdout (messages per
topic, time span, samples dropped for NaN); bad input gives one line on stderr and exit
status 2, and no bag. Needs no rclpy.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from es_msgs_py.bag import STORAGES
from es_recordings.labimport.errors import LabImportError
from es_recordings.labimport.guess import guess_map
from es_recordings.labimport.importer import import_recording
from es_recordings.labimport.mapfile import load_map
from es_recordings.labimport.sources import open_source

EXIT_BAD_INPUT = 2
EXIT_INTERNAL_ERROR = 1


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="import",
        description="Import a lab recording (.mat, .h5/.hdf5, .csv/.tsv, .npz) into a "
        "contract bag, as a YAML map says.",
        epilog="Bad input: one line on stderr, exit 2, no bag left behind.",
    )
    parser.add_argument("recording", type=Path, help="the recording file")
    parser.add_argument("-o", "--output", type=Path, help="bag directory to create")
    parser.add_argument("--map", type=Path, help="YAML map: topics, variables, units, time")
    parser.add_argument("--storage", choices=STORAGES, default="mcap", help="default: mcap")
    parser.add_argument("--inspect", action="store_true",
                        help="list the variables and print a guessed map (YAML) to start from")
    parser.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    return parser


def _run(args: argparse.Namespace) -> int:
    if args.inspect:
        source = open_source(args.recording)
        try:
            sys.stdout.write(guess_map(source))
        finally:
            source.close()
        return 0
    if args.output is None or args.map is None:
        print("import: give -o BAG and --map MAP.yaml (or --inspect)", file=sys.stderr)
        return EXIT_BAD_INPUT
    summary = import_recording(args.recording, args.output, load_map(args.map), args.storage)
    if not args.quiet:
        print("\n".join(summary.lines()))
    return 0


def run(argv: Sequence[str] | None = None) -> int:
    """Run the tool; return the exit status."""
    args = _parser().parse_args(argv)
    try:
        return _run(args)
    except LabImportError as err:
        print(f"import: {err}".splitlines()[0], file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        print("import: out of memory reading the recording", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as err:  # last resort: a user sees one line, never a traceback
        message = f"import: internal error ({type(err).__name__}: {err}"
        print(f"{message.splitlines()[0]}); please report it with the file", file=sys.stderr)
        return EXIT_INTERNAL_ERROR


def main() -> None:
    """Console entry point."""
    sys.exit(run())


if __name__ == "__main__":
    main()
