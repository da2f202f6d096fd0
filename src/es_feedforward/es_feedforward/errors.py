"""The exception classes of es_feedforward, in one place (pure: no imports at all).

Every class subclasses ``ValueError``, so a generic handler (``run_node``'s exit 2, the
node's parameter-set check) still catches them, while a caller that wants "a parameters
file problem" or "a calibration problem" catches just that.

- :class:`FeedforwardConfigError`: a feedforward or compensation configuration is
  inconsistent or out of range.
- :class:`FeedforwardInputError`: a set point or temperature grid of the wrong shape.
- :class:`ParameterError`: parameter values (node parameters or a file's) do not give a
  valid configuration; :class:`ParamsFileError` a ROS 2 parameters file cannot be read.
- :class:`CalibrationError` and its subclasses: the calibration cannot use its input
  (:class:`CalibrationInputError`) or cannot fit a model (:class:`CalibrationFitError`);
  a streamed recording does not hold what it promised (:class:`RecordingError`).
"""

from __future__ import annotations

__all__ = [
    "CalibrationError",
    "CalibrationFitError",
    "CalibrationInputError",
    "FeedforwardConfigError",
    "FeedforwardInputError",
    "ParameterError",
    "ParamsFileError",
    "RecordingError",
]


class FeedforwardConfigError(ValueError):
    """A feedforward or compensation configuration is inconsistent or out of range."""


class FeedforwardInputError(ValueError):
    """A set point or temperature grid does not have the configured shape."""


class ParameterError(ValueError):
    """Parameter values do not give a valid feedforward configuration (reason in the text)."""


class ParamsFileError(ParameterError):
    """A ROS 2 parameters file cannot be read or holds no parameters for the node."""


class CalibrationError(ValueError):
    """The calibration cannot give a result from its input; the message says why."""


class CalibrationInputError(CalibrationError):
    """Recordings the calibration cannot use (missing topic, wrong layout, too little data)."""


class CalibrationFitError(CalibrationError):
    """A model cannot be fitted to usable data (singular, no convergence, no candidate)."""


class RecordingError(CalibrationError):
    """A recording that does not hold what it promised (a skipped index, a column not kept)."""
