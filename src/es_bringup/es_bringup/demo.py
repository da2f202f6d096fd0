"""``scripts/demo`` / ``ros2 run es_bringup demo``: the main job, end to end over ROS 2.

The product's story, in order, every step a separate process graph run by the bring-up
(:mod:`es_bringup.bringup`) and recorded into a bag:

1. characterisation: the simulator as a test stand (no feedforward; a signal-generator
   voltage program, a slow temperature ramp, interferometer noise), recorded like measured
   data, once for the single thesis actuator and once for the 12 x 12 mirror;
2. calibration: ``es_calibration calibrate`` on each bag, told nothing about the simulator;
   it writes the parameters YAML the feedforward node loads;
3. the scenarios ``thesis_ac``, ``thesis_dc_ac`` and ``dm_exposure``, each with
   ``uncompensated`` and every compensating mode, using the calibrated parameters;
4. one calibration loop end to end: a test-stand bag with an effect the model lacks, the
   effect found, the error before and after, and the closed-loop tracking with the
   parameters before and after the effect was added; then self-sensing
   (:mod:`es_bringup.selfsensing_demo`): a test stand with the resonance sweeps,
   ``calibrate_resonance``, and ``dm_exposure`` with 4 NTCs, 4 NTCs + self-sensing and an
   NTC per actuator;
5. the report (Markdown + PNG + summary.json) in the output folder named at the end.

Runs go in parallel (``--jobs``) in one ROS domain, each graph below its own namespace
(``/run0``, ``/run1``, ...; the bags keep the contract's topic names) so they never see each
other.

Modules: :mod:`es_bringup.demo_options` (what runs), :mod:`es_bringup.demo_runs` (graph runs),
:mod:`es_bringup.demo_calibration` (test stands, the calibration tool, the loop's
parameters), :mod:`es_bringup.demo_steps` (the steps above), :mod:`es_bringup.demo_text` (the
report's sections); this module is the command line.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import NoReturn

from es_bringup import selfsensing_demo
from es_bringup.demo_options import LONG_FACTOR, MODES, SCENARIOS, Options
from es_bringup.demo_runs import DemoError, Progress
from es_bringup.demo_steps import Demo
from es_sim_plant.scenario import resolve_scenario


def _now() -> str:
    return datetime.now(UTC).strftime("%Y%m%d-%H%M%S")


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def parse_args(argv: Sequence[str]) -> Options:
    """Parse the command line; exit 2 with one line when invalid."""
    parser = _OneLineParser(
        prog="demo",
        description="Characterise, calibrate, run every scenario and mode over ROS 2, report.",
    )
    parser.add_argument("--out", type=Path, help="output folder (default out/demo-<UTC time>)")
    parser.add_argument(
        "--long", action="store_true", help=f"{LONG_FACTOR:g}x longer (slower) temperature runs"
    )
    parser.add_argument("--jobs", type=int, default=3, help="graphs run in parallel (default 3)")
    parser.add_argument(
        "--scenarios", nargs="+", default=list(SCENARIOS), metavar="NAME", help="scenarios"
    )
    parser.add_argument("--modes", nargs="+", default=list(MODES), metavar="MODE", help="modes")
    parser.add_argument(
        "--no-loop", action="store_true", help="skip the calibration loop with an extra effect"
    )
    parser.add_argument(
        "--no-selfsensing", action="store_true",
        help=f"skip the self-sensing section (runs when {selfsensing_demo.SCENARIO} is selected)",
    )  # fmt: skip
    ns = parser.parse_args(list(argv))
    if not 1 <= ns.jobs <= 8:
        parser.error(f"--jobs must be 1..8, got {ns.jobs}")
    unknown = [m for m in ns.modes if m not in MODES]
    if unknown:
        parser.error(f"unknown mode(s) {unknown}; known: {list(MODES)}")
    for name in ns.scenarios:
        try:
            resolve_scenario(name)
        except ValueError as err:
            parser.error(str(err))
    modes = tuple(dict.fromkeys(["uncompensated", *ns.modes]))
    out = ns.out or Path("out") / f"demo-{_now()}"
    if out.exists() and any(out.iterdir()):
        parser.error(f"--out {out} exists and is not empty")
    return Options(
        out, ns.long, ns.jobs, tuple(ns.scenarios), modes, not ns.no_loop,
        not ns.no_selfsensing and selfsensing_demo.SCENARIO in ns.scenarios,
    )  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo from the command line; return the exit code."""
    options = parse_args(sys.argv[1:] if argv is None else argv)
    progress = Progress()
    options.out.mkdir(parents=True, exist_ok=True)
    progress(f"output folder: {options.out}")
    demo = Demo(options, progress)
    try:
        report = demo.run()
    except KeyboardInterrupt:
        demo.runner.interrupt()
        progress("interrupted; every node stopped")
        return 130
    except (DemoError, ValueError, OSError) as err:
        demo.runner.interrupt()
        print(f"demo: error: {err}", file=sys.stderr)
        return 1
    finally:
        demo.runner.shutdown()
    progress(f"done in {progress.elapsed:.0f} s. Report: {report}")
    progress(f"summary: {options.out / 'summary.json'}; bags: {demo.dirs['bags']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
