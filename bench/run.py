"""Run the es_dm benchmark suite and write ``bench.md`` (tables) and ``bench.json`` (records).

Usage (from the repository root; ``scripts/bench`` bootstraps the venv and calls this)::

    .venv/bin/python bench/run.py [-o OUT] [--quick | --full] [--only SECTION ...] [--no-profile]

Sections (``--only``): ``kernels`` (bench_kernels.py), ``convert`` (bench_convert.py),
``feedforward`` (the feedforward node over DDS against a plain rclpy relay, relay.py),
``lockstep`` (plant, thermal and feedforward processes in lockstep on ``dm_exposure``),
``recorder`` (the recorder's memory while it records a 32 x 32 lockstep run),
``calibrate`` (bench_calibrate.py), ``thermal`` (bench_thermal.py), ``calibration_loop``
(bench_calibration_loop.py: characterise, calibrate, closed loop per effect family; writes
``calibration_loop.md``/``.json``), ``unlisted_loop`` (bench_unlisted_loop.py: the same on the
independent stand with an effect in no registry list, the law alone, the registry, the
discovered terms; writes ``unlisted_loop.md``/``.json``), ``import`` (bench_import.py: lab
recordings into bags, time and peak memory), ``scale`` (bench_scale.py: the feedforward node at
66 x 66 / 2 kHz and 128 x 128 / 1 kHz), ``lockstep_scale`` (bench_lockstep_scale.py: the closed
loop at 32 x 32 and 64 x 64), ``multihost`` (bench_multihost.py: 64 x 64 at 1 kHz across two
network namespaces; needs root), ``selfsensing`` (bench_selfsensing.py, offline cores). Peak
memory of every node process comes with the sections that start them. ``identify`` (the
identification sweep of standgen.identify on standgen bags, its own report in OUT/identify) is
not in the default selection: run it with ``--only identify``; nor is ``calibrate_stream``
(bench_calibrate_stream.py: streamed calibration of 64 x 64 and 128 x 128 bags of many GB).

Every figure is the median of repeated runs with their min and max (``summary.md``: the
compact table the README shows). ``bench.json`` holds
``{"date", "command", "machine", "settings", "records", "references", "notes", "failures"}``;
``records`` has one ``{"name", "n", "median", "min", "max", "unit", "ratio"}`` per figure with
the names of issue 9 (``ratio`` null where there is no floor or relay); ``references`` holds
the floors and the relay in the same format. A section that fails is reported in
``failures`` and in bench.md, the others still run; the exit code is then 1.

DDS runs use ROS_DOMAIN_ID from the environment (default 1 + pid % 101) and localhost
discovery only. Nothing here is asserted: targets are compared in the notes.

Layout: each section is a module ``bench/sections/<module>.py`` with ``run(context)`` (a
:class:`common.benchlib.Context`: settings, results, output folder), listed once in
``SECTIONS`` below; the benchmarks proper are ``bench/bench_*.py``; what they share is the
package ``bench/common/`` (``benchlib``: settings, records, node processes, waits;
``dds_client``: the in-process DDS client; ``reporting``: the report files; ``relay``,
``probe_node``, ``load``: helpers run as processes of their own). Adding a section is
one new module and one line of ``SECTIONS``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import importlib
import sys
import time
import traceback
from collections.abc import Sequence
from pathlib import Path

from common.benchlib import Context, Results, Settings, machine_info  # sets the DDS environment
from common.reporting import write_report, write_summary

#: Every section, in the order they run: ``--only`` name -> module with ``run(context)``.
SECTIONS: dict[str, str] = {
    "kernels": "sections.kernels",
    "convert": "sections.convert",
    "feedforward": "sections.feedforward",
    "lockstep": "sections.lockstep",
    "recorder": "sections.recorder",
    "calibrate": "sections.calibrate",
    "thermal": "sections.thermal",
    "calibration_loop": "sections.calibration_loop",
    "unlisted_loop": "sections.unlisted_loop",
    "import": "sections.lab_import",
    "scale": "sections.scale",
    "lockstep_scale": "sections.lockstep_scale",
    "multihost": "sections.multihost",
    "selfsensing": "sections.selfsensing",
    "identify": "sections.identify",
    "teardown": "sections.teardown",
    "feedforward_load": "sections.feedforward_load",
    "flow": "sections.flow",
    "calibrate_stream": "sections.calibrate_stream",
}
#: Sections run when ``--only`` is not given (the identification sweep has its own command).
DEFAULT_SECTIONS = tuple(name for name in SECTIONS if name not in ("identify", "calibrate_stream"))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the selected sections and write the report; return 1 if a section failed."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%d-%H%M%S")
    parser.add_argument("-o", "--output", type=Path, default=Path(f"out/bench-{stamp}"))
    parser.add_argument("--quick", action="store_true",
                        help="one run of each figure, shorter runs (about 1.5 minutes)")
    parser.add_argument("--full", action="store_true",
                        help="the long samples too: 50 Ctrl-C stops of each kind in the "
                             "teardown section (default 5, --quick 2)")
    parser.add_argument("--only", nargs="+", choices=SECTIONS, default=list(DEFAULT_SECTIONS))
    parser.add_argument("--no-profile", action="store_true",
                        help="skip the cProfile runs of the nodes and the calibration")
    parser.add_argument("--calibrate-seconds", type=float, default=None,
                        help="seconds of data of the 32 x 32 calibration case (300 = issue 9)")
    args = parser.parse_args(argv)
    settings = Settings.create(args.quick, profile=not args.no_profile,
                               calibrate_large=args.calibrate_seconds)
    machine = machine_info()
    date = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    command = " ".join(["bench/run.py", *(argv if argv is not None else sys.argv[1:])])
    results = Results()
    context = Context(settings, results, args.output, args.quick, full=args.full)
    for name in args.only:
        start = time.monotonic()
        print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        try:
            importlib.import_module(SECTIONS[name]).run(context)
        except Exception as err:
            results.failures.append(f"{name}: {type(err).__name__}: {err}".splitlines()[0])
            traceback.print_exc()
        print(f"[bench] {name} done in {time.monotonic() - start:.0f} s", file=sys.stderr,
              flush=True)
        write_report(args.output, results, machine, settings, date=date, command=command)
        write_summary(args.output, results, machine, date)
    print(f"[bench] wrote {args.output / 'bench.md'} and {args.output / 'bench.json'}",
          file=sys.stderr)
    return 1 if results.failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
