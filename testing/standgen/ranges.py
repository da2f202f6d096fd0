"""Effect families of the test stand and their parameter ranges: the one table.

Every range the generator draws from is a row of :data:`RANGES`; README.md beside this
package prints the same rows (``python -m standgen.ranges`` writes the Markdown table).
Times of the thermal effects are for the stand's time-compressed runs (a Peltier ramp of
12 degC in about 40 % of a run of a minute, like the project's characterisation scenario):
physical lags of 10-60 s shrink with the run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

#: Canonical effect names (the calibration's candidates use exactly these).
FAMILIES: Final = (
    "delay",
    "hysteresis",
    "self_heating",
    "frequency_dispersion",
    "sensor_lag",
    "drift",
    "coupling",
    "thermal_expansion",
    "temperature_curvature",
)


@dataclass(frozen=True)
class Range:
    """One drawn parameter: ``low``..``high`` in ``unit`` (``log``: drawn log-uniformly)."""

    family: str
    name: str
    low: float
    high: float
    unit: str
    note: str
    log: bool = False

    def draw(self, rng: np.random.Generator) -> float:
        """Draw one value."""
        if self.log:
            return float(np.exp(rng.uniform(np.log(self.low), np.log(self.high))))
        return float(rng.uniform(self.low, self.high))


RANGES: Final = (
    Range("delay", "delay_samples", 0.3, 15.0, "command periods",
          "transport delay; fractional part kept in [0.15, 0.85] so it is never whole"),
    Range("hysteresis", "operators", 1, 3, "play operators", "N, drawn as an integer"),
    Range("hysteresis", "threshold_v", 5.0, 60.0, "V", "half-width of each play operator"),
    Range("hysteresis", "total_weight", 0.04, 0.15, "1",
          "sum of the non-negative operator weights (split at random); the rest is the "
          "plain drive"),
    Range("self_heating", "gain", 8e-6, 3e-5, "degC/(V^2 Hz)",
          "steady actuator excess over its sensor for a sine of amplitude A at f: gain f A^2"),
    Range("self_heating", "tau_s", 0.5, 3.0, "s", "thermal time constant of the excess"),
    Range("frequency_dispersion", "strength", 0.04, 0.12, "1",
          "Debye relaxation of the polarisation: drive reduced by this fraction far above "
          "the corner"),
    Range("frequency_dispersion", "corner_hz", 2.0, 20.0, "Hz", "relaxation corner", log=True),
    Range("sensor_lag", "tau_s", 1.0, 4.0, "s",
          "first-order lag of the NTC reading behind the actuator"),
    Range("drift", "fraction", 0.02, 0.06, "1", "aging of M: D1 / (D0 + D1)"),
    Range("drift", "tau_fraction", 0.2, 0.5, "run lengths", "tau of exp(-(t/tau)^nu)"),
    Range("drift", "nu", 0.6, 1.4, "1", "stretch exponent"),
    Range("coupling", "coefficient", 0.02, 0.08, "1",
          "z = z_free + c lap(z_free) through the face sheet (grids >= 2 x 2)"),
    Range("thermal_expansion", "alpha_m_per_degc", 0.3e-9, 0.6e-9, "m/degC",
          "voltage independent, z += alpha (T - 40 degC)"),
    Range("temperature_curvature", "m3_abs", 0.15e-18, 0.5e-18, "m^2/V^2/degC^2",
          "magnitude of m3, random sign"),
    Range("temperature_curvature", "k3_abs", 0.1e-9, 0.4e-9, "m/V/degC^2",
          "magnitude of k3, random sign"),
)

#: Conditions of every recording (not effects): what a lab stand varies.
STAND_RANGES: Final = (
    Range("stand", "command_rate_hz", 250.0, 5000.0, "Hz",
          "command and interferometer, same clock (sweep picks 250, 500, 1000, 2000, 5000)"),
    Range("stand", "temperature_rate_hz", 1.0, 100.0, "Hz", "NTC sampling"),
    Range("stand", "interferometer_noise_m", 0.3e-9, 1.0e-9, "m rms",
          "white, plus a 0.1 nm quantisation step"),
    Range("stand", "sensor_noise_degc", 0.01, 0.03, "degC rms", "plus a 0.01 degC quantisation"),
    Range("stand", "spread_m2", 0.02, 0.02, "1 sd", "per-actuator scatter of m2"),
    Range("stand", "spread_k2", 0.01, 0.01, "1 sd", "per-actuator scatter of k2"),
    Range("stand", "base_temperature_degc", 40.0, 52.0, "degC",
          "Peltier ramp 40 -> 52 -> 40 (hold at the top), smoothed by the Peltier's lag"),
    Range("stand", "voltage_v", -350.0, 350.0, "V",
          "program of 0.8-2 s segments: sines 0.1-100 Hz, two tones, DC steps, ramps, "
          "DC + AC; amplitude <= min(250 V, 1250 V Hz / f)"),
)


#: Recording faults of the stand (issue 33): sweep families of their own, the calibration's
#: health KINDS name what it should report. ``independent_drive`` is a drive, not a fault.
FAULT_FAMILIES: Final = (
    "clock_rate",
    "sensor_frozen",
    "sensor_flat",
    "sensor_jump",
    "actuator_weak",
    "actuator_dead",
    "receive_jitter",
    "independent_drive",
)

FAULT_RANGES: Final = (
    Range("clock_rate", "ppm", 30.0, 100.0, "ppm",
          "displacement logger's clock fast vs the command's: its stamps are t (1 + ppm 1e-6)"),
    Range("sensor_frozen", "freeze_fraction", 0.3, 0.6, "run lengths",
          "one sensor holds its last reading from this time on"),
    Range("sensor_flat", "value_degc", 20.0, 30.0, "degC",
          "one sensor reads this constant from the start (a disconnected NTC's default)"),
    Range("sensor_jump", "step_degc", 1.0, 3.0, "degC",
          "one sensor's reading steps by +-this at each of 2-3 instants (kept until the next)"),
    Range("actuator_weak", "fraction", 0.5, 0.7, "x neighbours' gain",
          "one actuator's displacement scaled by this (a cracked actuator)"),
    Range("actuator_dead", "fraction", 0.0, 0.0, "x neighbours' gain",
          "one actuator does not move (interferometer noise only)"),
    Range("receive_jitter", "jitter_periods", 0.2, 1.0, "command periods",
          "displacement receive stamps late by an exponential delay of this mean"),
    Range("receive_jitter", "burst_late_s", 0.03, 0.12, "s",
          "2-3 bursts: every message of a 0.1-0.3 s window arrives together, this late"),
    Range("independent_drive", "cells", 4, 64, "actuators",
          "each actuator its own program: segment edges at different times (up to 8 x 8)"),
)

#: Physical effects in no list of the product's registry (issue 34): sweep families whose
#: only right answer is a discovered term (any registry effect accepted is a stand-in).
UNLISTED_FAMILIES: Final = (
    "slew_limit",
    "amplifier_droop",
    "periodic_nonlinearity",
    "creep",
    "thermal_gradient",
)

UNLISTED_RANGES: Final = (
    Range("slew_limit", "rate_v_per_s", 3e3, 1e4, "V/s",
          "amplifier slew-rate limit on the drive (drive side; not compensable beyond it)",
          log=True),
    Range("amplifier_droop", "strength", 0.03, 0.08, "1",
          "amplifier gain droops with output current: V (1 - s min(abs(dV/dt) / 5 kV/s, 1)) "
          "(drive side)"),
    Range("periodic_nonlinearity", "amplitude_m", 0.6e-9, 1.5e-9, "m",
          "interferometer periodic error: a sin(4 pi z / lambda + phi), lambda 633 nm, plus "
          "a quarter of it at twice the rate (metrology; output side, not the mirror's)"),
    Range("creep", "gamma_per_decade", 0.01, 0.03, "1",
          "logarithmic creep: z + gamma sum of lags of z at 10 ms, 100 ms, 1 s, 10 s"),
    Range("thermal_gradient", "lag_s", 0.5, 1.5, "s",
          "actuator T offset -lag x (neighbours' mean dT/dt) x depth (0 at the grid's rim, 1 "
          "at its centre): heat reaches the centre late; the sensors on the rim mounts miss it"),
)


def range_of(family: str, name: str) -> Range:
    """Return the row ``family``/``name`` of the tables.

    Raises:
        KeyError: no such row.

    """
    for row in (*RANGES, *STAND_RANGES, *FAULT_RANGES, *UNLISTED_RANGES):
        if row.family == family and row.name == name:
            return row
    raise KeyError(f"no range {family}.{name}")


def markdown_table(rows: tuple[Range, ...] = (*RANGES, *STAND_RANGES)) -> str:
    """Return ``rows`` as a Markdown table (default: effects and stand, the README's copy)."""
    lines = ["| family | parameter | low | high | unit | note |", "|---|---|---:|---:|---|---|"]
    for row in rows:
        scale = "log-uniform; " if row.log else ""
        lines.append(f"| `{row.family}` | {row.name} | {row.low:g} | {row.high:g} | {row.unit} "
                     f"| {scale}{row.note} |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown_table(), markdown_table(FAULT_RANGES), markdown_table(UNLISTED_RANGES),
          sep="\n\n")
