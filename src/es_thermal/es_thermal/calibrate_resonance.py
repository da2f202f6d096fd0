"""``calibrate_resonance``: per-actuator resonance laws for self-sensing from a bag.

Usage: ``ros2 run es_thermal calibrate_resonance BAG -o OUT.yaml [--reference-temperature T]``
(console script ``es_thermal-calibrate-resonance``). Reads /dm/resonance, /dm/command and
/dm/temperature/raw of a characterisation run (Peltier ramp of the whole mirror and a
voltage program, see :mod:`es_thermal.resonance_calibration`), fits f0, a_T and a_V with
their uncertainties per actuator and writes them as the thermal node's parameters file
(``resonance.*``). One summary line on stdout; channels that could not be calibrated are
named on stderr. Bad input (missing bag or topic, wrong layout, no ramp, unwritable
output) ends with one line on stderr and exit status 2. Needs no rclpy.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import numpy as np

from es_thermal.resonance_calibration import (
    ResonanceCalibrationError,
    calibrate_bag,
    write_thermal_params,
)

EXIT_BAD_INPUT = 2


def main(argv: Sequence[str] | None = None) -> int:
    """Run the tool; return the exit status (0 ok, 2 bad input)."""
    parser = argparse.ArgumentParser(
        prog="calibrate_resonance",
        description="Fit every actuator's resonance law f = f0 + a_T (T - T0) + a_V |V| "
        "from a characterisation bag and write the thermal node's parameters file.",
    )
    parser.add_argument("bag", help="characterisation bag (MCAP or sqlite3)")
    parser.add_argument("-o", "--output", required=True, help="parameters YAML to write")
    parser.add_argument(
        "--reference-temperature", type=float, default=None,
        help="T0, degC (default: the stage temperature's mean)",
    )  # fmt: skip
    ns = parser.parse_args(argv)
    try:
        fit = calibrate_bag(ns.bag, ns.reference_temperature)
        write_thermal_params(fit, ns.output)
    except ResonanceCalibrationError as err:
        print(f"calibrate_resonance: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as err:
        print(f"calibrate_resonance: cannot write {ns.output}: {err.strerror}", file=sys.stderr)
        return EXIT_BAD_INPUT
    working = np.ones(fit.f0_hz.size, bool)
    working[list(fit.disabled)] = False
    print(
        f"calibrated {int(working.sum())} of {fit.f0_hz.size} channels: a_T median "
        f"{np.median(fit.a_t_hz_per_degc.ravel()[working]):.1f} Hz/degC, a_V median "
        f"{np.median(fit.a_v_hz_per_v.ravel()[working]):.1f} Hz/V, f0 sd median "
        f"{np.median(fit.f0_sd_hz.ravel()[working]):.2g} Hz, noise {fit.noise_hz:.3g} Hz, "
        f"T0 {fit.reference_temperature:g} degC -> {ns.output}"
    )
    if fit.disabled:
        print(
            f"calibrate_resonance: not calibrated (disabled): channels {list(fit.disabled)}",
            file=sys.stderr,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
