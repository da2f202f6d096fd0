"""The exception classes of es_bringup, in one place (pure: no imports at all).

Every class subclasses ``ValueError``, so a generic handler still catches them.

- :class:`RunDataError`: a run's recording cannot be evaluated (shapes that differ between
  topics, topics missing, too short for the period asked) (:mod:`es_bringup.metrics`,
  :mod:`es_bringup.analysis`).
- :class:`SupervisorError`: a process set the supervisor cannot run (a name used twice, no
  primary process) (:mod:`es_bringup.supervisor`).
- :class:`CalibrationFilesError`: a calibration directory or parameters file that cannot be
  used (:mod:`es_bringup.calibration_files`).
"""

from __future__ import annotations

__all__ = ["CalibrationFilesError", "RunDataError", "SupervisorError"]


class RunDataError(ValueError):
    """A recorded run that cannot be evaluated; the message says what is missing or wrong."""


class SupervisorError(ValueError):
    """A set of processes the supervisor cannot start or watch."""


class CalibrationFilesError(ValueError):
    """A calibration directory or parameters file that cannot be used (one readable line)."""
