"""The exception classes of es_calibration, in one place (pure: no imports at all).

Every class subclasses ``ValueError``, so a generic handler (a CLI's exit 2) still catches
them, while a caller that wants "a calibration problem" catches just that.

- :class:`CalibrationError` and its subclasses: the calibration cannot use its input
  (:class:`CalibrationInputError`) or cannot fit a model (:class:`CalibrationFitError`);
  a streamed recording does not hold what it promised (:class:`RecordingError`).
"""

from __future__ import annotations

__all__ = [
    "CalibrationError",
    "CalibrationFitError",
    "CalibrationInputError",
    "RecordingError",
]


class CalibrationError(ValueError):
    """The calibration cannot give a result from its input; the message says why."""


class CalibrationInputError(CalibrationError):
    """Recordings the calibration cannot use (missing topic, wrong layout, too little data)."""


class CalibrationFitError(CalibrationError):
    """A model cannot be fitted to usable data (singular, no convergence, no candidate)."""


class RecordingError(CalibrationError):
    """A recording that does not hold what it promised (a skipped index, a column not kept)."""
