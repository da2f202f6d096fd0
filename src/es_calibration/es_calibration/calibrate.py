"""``calibrate``: fit the actuator model to measured-data bags and find what it still misses.

Usage: ``ros2 run es_calibration calibrate BAG [BAG ...] -o OUTDIR`` (console script
``es_calibration-calibrate``); a lab recording (.mat, .h5/.hdf5, .csv/.tsv, .npz) takes the
place of a bag with ``--map MAP.yaml``: it goes through the ``import`` tool's code
(:mod:`es_recordings.labimport`) into a temporary bag in OUTDIR first. Reads /dm/command,
/dm/displacement and /dm/temperature (or /dm/temperature/raw) from each bag (MCAP or
sqlite3), then writes into OUTDIR:

- ``report.md`` and its PNG figures: every step (alignment, law fit, held-out residual
  structure, candidate effects, accepted effects, unexplained structure);
- ``calibration.json``: fitted parameters with uncertainties, accepted effects with the
  held-out RMS before and after each, the noise floor and the unexplained structure (schema in
  :mod:`es_calibration.output.schema`);
- ``feedforward_params.yaml``: the ROS 2 parameters of the ``feedforward`` node (per-actuator
  ``law.*`` maps and the ``compensation.*`` of the accepted effects);
- ``thermal_params.yaml``: the ROS 2 parameters of the ``thermal`` node the calibration
  learned about the sensors (``sensor_lag_tau`` per sensor or for all, ``sensor_offsets``,
  ``sensor_offsets_sd``; :mod:`es_calibration.output.thermal_file`), named in
  calibration.json's ``thermal_params``. Lags are written physical: a recording of a
  simulator's shortened scenario gives its ``--time-scale``. A bring-up given both files
  lets the thermal node undo the sensor's lag and switches the feedforward's lead off.

Bags are streamed (:mod:`es_calibration.data.bagstream`): two passes in batches of
messages, the whole grid only at the samples the fit uses: what grows with the recording's
length is the 8 x 8 screening block at full rate and the grid's temperature at the sensor rate
(1/64 of a 64 x 64 record, and less), not the grid at full rate. The grid-wide refit runs in
actuator tiles (:mod:`es_calibration.grid.tiles`), serially or as tasks on Dask:
``--workers N`` starts a local cluster, ``--scheduler tcp://host:port`` uses a running one
(Dask is imported only then). On a long record the effect search sees at most
``--search-budget`` sample-actuator values of the screening block, in windows spread over the
whole run (:mod:`es_calibration.data.searchspan`); the grid-wide refit draws from the
whole record.

The tool is told nothing about how the data were made. Bad input (missing or empty topics,
a single message, mismatched grids, too short, all-NaN, corrupt, a bag given twice, bags
overlapping in time) ends with one line on stderr and exit status 2, as does an output
directory that cannot be created or written; NaN samples are dropped and counted in the
report. A topic without messages counts as absent (an empty /dm/temperature falls back to
/dm/temperature/raw).

Time stamps are the bag's receive stamps. Messages are used in stamp order, messages sharing
a stamp in recording order (so a recorder writing slightly out of order is corrected; a clock
that jumps back mid-recording cannot be told from that, record such runs as separate bags).
Repeated stamps (a recorder lagging under sim time): a run of equal temperature stamps is
spread evenly up to the next stamp; when /dm/command and /dm/displacement have as many
messages each (lock-step), they are paired by message order (displacement i answers command
i) on a rebuilt time base; otherwise every displacement sample with an ambiguous pairing (its
stamp shared with another displacement, or its command in effect one of several commands
sharing a stamp) is dropped and counted, and if fewer than 200 usable samples remain
the tool stops with one line and exit status 2. Report and calibration.json say which rule
was applied.

Gaps (an interval between messages of a topic longer than 3.5 median periods; a topic that
starts or ends more than that away from the displacement record): nothing is interpolated
across one. The displacement samples that would need its data are left out of fit and
scoring (a temperature gap: those inside it and within the half-window of dT/dt; a command
hole: from the next command's due time to 1 s after the hole, for delays and the hysteresis
state); each gap is listed with its start, length, missing messages and excluded samples
(``data.gaps`` in calibration.json, a table in the report). What no candidate explains is
stated in numbers (lines in Hz and nm, correlations with their slopes).

Recording health comes before the physics: faulty temperature sensors (frozen, flat, out of
range, jumping, dropping out, changing noise) are named and their samples taken from their
neighbours; after the fit, dead, weak, saturating and outlying actuators are named
(``health`` in calibration.json). An effect whose parameters lie outside what the record
can show, or that moves between the record's halves, is a stand-in: refused, or written
switched off. The verdict (``verdict`` in calibration.json, ``calibration.verdict`` in the
YAML) sets the exit status: 0 trusted, 3 provisional, 4 unusable (2 bad input, 1 internal
error). Needs no rclpy.
"""

from __future__ import annotations

import os

# One BLAS thread unless told otherwise, set before numpy loads OpenBLAS: the fits' products
# are small or thin (e.g. (64 x 6000, 28) grams), and OpenBLAS's threads only contend on a
# shared 2-core machine (such a gram: 13 ms on one thread, 320 ms with its threads at load 3).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import math
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from es_calibration.data.align import MIN_SAMPLES, CalibrationInputError
from es_calibration.data.bagstream import BagRecording
from es_calibration.data.gaps import GAP_FACTOR
from es_calibration.data.searchspan import SEARCH_BUDGET
from es_calibration.grid.tiles import DASK_INSTALL_HINT, DEFAULT_TILE, DaskSetupError
from es_calibration.model.composite import CANDIDATES
from es_calibration.pipeline import Calibration, calibrate
from es_calibration.verdict import EXIT_STATUS
from es_recordings.labimport import LabImportError, import_recording, load_map

EXIT_BAD_INPUT = 2
EXIT_INTERNAL_ERROR = 1


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="calibrate",
        description="Calibrate the electrostrictive actuator model from measured-data bags.",
        epilog=(
            "Messages are used in stamp order (equal stamps in recording order); empty topics "
            "count as absent. Repeated stamps: runs of equal stamps are spread up to the next "
            "stamp; command and displacement with equal message counts are paired by order, "
            "otherwise ambiguous displacement samples are dropped and counted (exit 2 if "
            f"fewer than {MIN_SAMPLES} usable samples remain). Gaps (> {GAP_FACTOR:g} median "
            "periods between messages of a topic) are never interpolated across: the samples "
            "needing their data are left out, counted and listed. Exit status: 0 trusted, "
            "3 provisional (usable with care: the reasons are in calibration.json's verdict), "
            "4 unusable (do not load the parameters file), 2 bad input (one line on stderr), "
            "1 internal error."
        ),
    )
    parser.add_argument(
        "bags",
        nargs="+",
        type=Path,
        help="rosbag2 directories (MCAP or sqlite3), or lab recordings (with --map)",
    )
    parser.add_argument(
        "--map",
        type=Path,
        help="import map (YAML) of the lab recordings given (.mat, .h5, .csv, .tsv, .npz); "
        "see `ros2 run es_recordings import --inspect REC`",
    )
    parser.add_argument("-o", "--output", required=True, type=Path, help="output directory")
    parser.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        help="time scale of the recording (a simulator's shortened scenario; default 1: "
        "physical): the thermal node's file holds the sensor lag divided by it",
    )
    parser.add_argument(
        "--candidates",
        default=",".join(CANDIDATES),
        help="comma-separated candidate effects to test (default: all)",
    )
    parser.add_argument(
        "--tile",
        type=int,
        default=DEFAULT_TILE,
        help="edge of the actuator tiles of the grid-wide refit (default %(default)s); "
        "a tile as large as the grid is one joint fit",
    )
    parser.add_argument(
        "--search-budget",
        type=int,
        default=SEARCH_BUDGET,
        help="sample-actuator values the effect search sees at most (default %(default)s); "
        "a longer record is searched on windows spread over it",
    )
    parser.add_argument(
        "--workers",
        type=int,
        help="run the tiles on a local Dask cluster of N worker processes",
    )
    parser.add_argument(
        "--scheduler",
        help="run the tiles on an existing Dask cluster (tcp://host:port)",
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    return parser


def _as_bags(paths: Sequence[Path], map_path: Path | None, work: Path, quiet: bool
             ) -> list[Path]:
    """Return ``paths`` with each lab recording (a file) imported into a bag in ``work``.

    Raises:
        CalibrationInputError: a file without ``--map``, ``--map`` without a file, or a
            recording given twice.
        LabImportError: the map or a recording cannot be imported.

    """
    recordings = [p for p in paths if p.is_file()]
    if map_path is None:
        if recordings:
            raise CalibrationInputError(
                f"{recordings[0]} is a file, not a bag: give --map MAP.yaml to import a lab "
                "recording (ros2 run es_recordings import --inspect REC guesses one)"
            )
        return list(paths)
    if not recordings:
        raise CalibrationInputError("--map is given but no lab recording (only bag directories)")
    if len({p.resolve() for p in recordings}) < len(recordings):
        raise CalibrationInputError("a recording is given twice")
    import_map = load_map(map_path)
    bags = []
    for i, path in enumerate(paths):
        if path not in recordings:
            bags.append(path)
            continue
        summary = import_recording(path, work / f"{i}-{path.name}", import_map)
        if not quiet:
            print("\n".join(f"import {path}: {line}" for line in summary.lines()[1:]))
        bags.append(summary.bag)
    return bags


def _calibrate(
    recording: BagRecording, candidates: tuple[str, ...], args: argparse.Namespace
) -> Calibration:
    """Calibrate, the tiles on Dask when ``--workers`` or ``--scheduler`` is given.

    Raises:
        CalibrationInputError: bad data.
        DaskSetupError: the Dask cluster cannot be started or reached, or Dask is not installed.

    """
    if args.workers is None and args.scheduler is None:
        return calibrate(recording, candidates, tile=args.tile, search_budget=args.search_budget)
    try:
        from es_calibration.grid.dask_tiles import dask_map  # Dask only when asked for
    except ImportError as err:  # the optional dependency is not installed
        raise DaskSetupError(f"{DASK_INSTALL_HINT} ({err})") from None

    with dask_map(args.workers, args.scheduler) as run_tiles:
        return calibrate(recording, candidates, tile=args.tile, run=run_tiles,
                         search_budget=args.search_budget)


def run(argv: Sequence[str] | None = None) -> int:
    """Run the tool; return the exit status."""
    args = _parser().parse_args(argv)
    candidates = tuple(c for c in args.candidates.split(",") if c)
    unknown = sorted(set(candidates) - set(CANDIDATES))
    if unknown:
        print(
            f"calibrate: unknown candidate(s) {', '.join(unknown)}; known: {', '.join(CANDIDATES)}",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    if args.tile < 1 or args.search_budget < 1 or (args.workers is not None and args.workers < 1):
        print("calibrate: --tile, --search-budget and --workers must be at least 1",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    if not math.isfinite(args.time_scale) or args.time_scale <= 0.0:
        print(f"calibrate: --time-scale must be finite and > 0, got {args.time_scale}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        args.output.mkdir(parents=True, exist_ok=True)  # fail before a long calibration
    except OSError as err:
        print(
            f"calibrate: cannot create output directory {args.output}: {err.strerror or err}",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    try:
        with tempfile.TemporaryDirectory(prefix=".import-", dir=args.output) as work:
            bags = _as_bags(args.bags, args.map, Path(work), args.quiet)
            clock = time.perf_counter()
            recording = BagRecording(bags)
            first_pass = time.perf_counter() - clock
            cal = _calibrate(recording, candidates, args)
            cal.timings_s = {"bag first pass": first_pass, **cal.timings_s}
        # matplotlib and the feedforward configuration are only needed once there is a result
        from es_calibration.output.report import write_report
        from es_calibration.output.schema import write_calibration_json, write_parameters_yaml
        from es_calibration.output.thermal_file import thermal_section, write_thermal_params
        from es_feedforward.param_file import CALIBRATION_FILE_NAME as FEEDFORWARD_FILE
        from es_thermal.sensor_params import CALIBRATION_FILE_NAME as THERMAL_FILE

        notes = write_parameters_yaml(cal, args.output / FEEDFORWARD_FILE)
        write_thermal_params(cal, args.output / THERMAL_FILE, args.time_scale)
        thermal = thermal_section(cal, args.time_scale)
        write_calibration_json(cal, args.output / "calibration.json", thermal)
        report = write_report(cal, args.output, notes)
    except (CalibrationInputError, LabImportError, DaskSetupError, OSError) as err:
        print(f"calibrate: {err}".splitlines()[0], file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        print("calibrate: out of memory reading the bags", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as err:  # last resort: a user sees one line, never a traceback
        message = f"calibrate: internal error ({type(err).__name__}: {err}"
        print(f"{message.splitlines()[0]}); please report it with the bag", file=sys.stderr)
        return EXIT_INTERNAL_ERROR
    if not args.quiet:
        found = ", ".join(
            e.name + ("" if e.enabled else " (not confirmed, off)") for e in cal.effects
        ) or "none"
        print(
            f"held-out RMS {cal.base.heldout_rms * 1e9:.4g} nm -> "
            f"{cal.final.heldout_rms * 1e9:.4g} nm (noise floor "
            f"{cal.noise_floor_m * 1e9:.4g} nm); effects added: {found}; report: {report}"
        )
        reasons = "; ".join(cal.verdict.reasons)
        print(f"verdict: {cal.verdict.level}" + (f" ({reasons})" if reasons else ""))
    return EXIT_STATUS[cal.verdict.level]


def main() -> None:
    """Console entry point."""
    sys.exit(run())


if __name__ == "__main__":
    main()
