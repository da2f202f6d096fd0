"""Actuator faults read from the fitted law: outliers, dead, weak and saturating actuators.

At the record's mean temperature each actuator's M, k and largest slope d_max (the gain)
are compared with the grid's by a robust spread (median and MAD):

- ``actuator_dead``: d_max below ``DEAD_RATIO`` of the grid's median (or not a number);
- ``actuator_weak``: d_max below ``WEAK_RATIO`` of it (a cracked actuator);
- ``actuator_saturating``: z_sat, the most it can stroke, below ``SATURATION_RATIO`` of the
  grid's median;
- ``actuator_outlier``: M, k or d_max more than ``OUTLIER_SIGMAS`` robust sigmas and
  ``OUTLIER_MIN_RELATIVE`` from the median (and not already named above).

Each finding says what the feedforward will do about it.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from es_calibration.health.findings import Finding
from es_common.arrays import FloatArray
from es_physics.laws import d_max, z_sat
from es_physics.params import ActuatorParams

#: Gain below this share of the grid's median: dead.
DEAD_RATIO: Final = 0.1
#: Gain below this share of the grid's median: weak.
WEAK_RATIO: Final = 0.8
#: Stroke (z_sat) below this share of the grid's median: saturating.
SATURATION_RATIO: Final = 0.5
#: Robust sigmas from the grid's median that make an outlier ...
OUTLIER_SIGMAS: Final = 6.0
#: ... when also this far from it, relatively (a very uniform grid has a tiny MAD).
OUTLIER_MIN_RELATIVE: Final = 0.1
_MAD_SIGMA: Final = 1.4826


def _ratio(values: FloatArray) -> FloatArray:
    """Return each value over the finite values' median."""
    finite = values[np.isfinite(values)]
    median = float(np.median(finite)) if finite.size else np.nan
    return np.asarray(values / median, np.float64)


def check_actuators(
    params: ActuatorParams, temperature: float, duration_s: float
) -> list[Finding]:
    """Name the actuators whose fitted law stands out from the grid's.

    Args:
        params: the fitted law, per-actuator maps (R, C).
        temperature: the record's mean temperature [degC].
        duration_s: the record's length [s] (a finding's span).

    """
    shape = np.shape(params.m2)
    if len(shape) != 2 or shape[0] * shape[1] < 3:
        return []  # too few actuators for a grid's spread
    cols = shape[1]
    with np.errstate(all="ignore"):
        measures = {
            "M": np.asarray(params.M(temperature), np.float64).ravel(),
            "k": np.asarray(params.k(temperature), np.float64).ravel(),
            "d_max": d_max(temperature, params).ravel(),
        }
        gain = _ratio(measures["d_max"])
        stroke = _ratio(z_sat(temperature, params).ravel())
    named: set[int] = set()
    found: list[tuple[int, str, float, str, str, str]] = []
    dead = ~(gain >= DEAD_RATIO)
    for a in np.flatnonzero(dead):
        found.append((int(a), "actuator_dead", float(gain[a]), "x grid median gain",
                      f"barely moves: its gain is {gain[a]:.2g} x the grid's median",
                      "flagged; no law can make it move: the feedforward drives it by its own "
                      "law up to v_limit and reports it there"))
    weak = ~dead & (gain < WEAK_RATIO)
    for a in np.flatnonzero(weak):
        found.append((int(a), "actuator_weak", float(gain[a]), "x grid median gain",
                      f"is weak: its gain is {100 * gain[a]:.0f} % of the grid's median",
                      "compensated by its own law in the parameters file (the feedforward "
                      f"drives it about {1 / np.sqrt(gain[a]):.2f}x harder)"))
    saturating = ~dead & (stroke < SATURATION_RATIO)
    for a in np.flatnonzero(saturating):
        found.append((int(a), "actuator_saturating", float(stroke[a]), "x grid median stroke",
                      f"saturates early: the most it strokes is {100 * stroke[a]:.0f} % of "
                      "the grid's median",
                      "set points beyond its stroke are limited and reported by the "
                      "feedforward (status saturated)"))
    named.update(a for a, *_ in found)
    for name, values in measures.items():
        finite = values[np.isfinite(values)]
        median = float(np.median(finite))
        spread = _MAD_SIGMA * float(np.median(np.abs(finite - median)))
        off = np.abs(values - median)
        outlier = (off > OUTLIER_SIGMAS * spread) & (off > OUTLIER_MIN_RELATIVE * abs(median))
        for a in np.flatnonzero(outlier):
            if int(a) in named:
                continue
            named.add(int(a))
            sigmas = off[a] / spread if spread > 0 else np.inf
            found.append((int(a), "actuator_outlier", float(values[a] / median),
                          f"x grid median {name}",
                          f"stands out: its {name} is {values[a] / median:.3g} x the grid's "
                          f"median ({sigmas:.3g} robust sigmas)",
                          "compensated by its own law in the parameters file"))
    findings = []
    for index, kind, value, unit, words, action in sorted(found):
        row, col = divmod(index, cols)
        subject = f"actuator {index} ({row}, {col})"
        findings.append(Finding(kind, subject, index, row, col, 0.0, float(duration_s), value,
                                unit, f"Actuator {index} ({row}, {col}) {words}.", action))
    return findings
