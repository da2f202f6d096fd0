"""The exception classes of es_thermal, in one place (pure: no imports at all).

Every class subclasses ``ValueError``, so a generic handler (the node's input callbacks)
still catches them, while a caller that wants "bad input" or "bad configuration" catches
just that.

- :class:`ThermalConfigError`: an estimator, filter, network, fault or self-sensing
  configuration is inconsistent or out of range.
- :class:`ThermalInputError`: data given at run time do not fit (shape, NaN/inf, no valid
  sensor, nothing to score).
- :class:`EstimatorStateError`: the estimator is asked for something before it has it.
- :class:`ConvergenceError`: a numerical design step did not converge (Kalman gain).
- :class:`CalibrationError`: resonance calibration arrays that do not fit the grid or are
  not usable (:mod:`es_thermal.selfsensing`).
- :class:`ResonanceCalibrationError`: a recording cannot give a resonance calibration
  (:mod:`es_thermal.resonance_calibration`).
"""

from __future__ import annotations

__all__ = [
    "CalibrationError",
    "ConvergenceError",
    "EstimatorStateError",
    "ResonanceCalibrationError",
    "ThermalConfigError",
    "ThermalInputError",
]


class ThermalConfigError(ValueError):
    """A configuration of the estimator or one of its parts is inconsistent or out of range."""


class ThermalInputError(ValueError):
    """Data given at run time do not fit (shape, NaN/inf, no valid sensor)."""


class EstimatorStateError(ValueError):
    """The estimator is asked for something before it has it (no state yet)."""


class ConvergenceError(ValueError):
    """A numerical design step (the Kalman gain's Riccati iteration) did not converge."""


class CalibrationError(ValueError):
    """Resonance calibration arrays that do not fit the grid or are not usable."""


class ResonanceCalibrationError(ValueError):
    """Input that cannot give a calibration (missing topic, wrong layout, too little data)."""
