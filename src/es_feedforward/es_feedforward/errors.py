"""The exception classes of es_feedforward, in one place (pure: no imports at all).

Every class subclasses ``ValueError``, so a generic handler (``run_node``'s exit 2, the
node's parameter-set check) still catches them, while a caller that wants "a parameters
file problem" catches just that.

- :class:`FeedforwardConfigError`: a feedforward or compensation configuration is
  inconsistent or out of range.
- :class:`FeedforwardInputError`: a set point or temperature grid of the wrong shape.
- :class:`ParameterError`: parameter values (node parameters or a file's) do not give a
  valid configuration; :class:`ParamsFileError` a ROS 2 parameters file cannot be read.
"""

from __future__ import annotations

__all__ = [
    "FeedforwardConfigError",
    "FeedforwardInputError",
    "ParameterError",
    "ParamsFileError",
]


class FeedforwardConfigError(ValueError):
    """A feedforward or compensation configuration is inconsistent or out of range."""


class FeedforwardInputError(ValueError):
    """A set point or temperature grid does not have the configured shape."""


class ParameterError(ValueError):
    """Parameter values do not give a valid feedforward configuration (reason in the text)."""


class ParamsFileError(ParameterError):
    """A ROS 2 parameters file cannot be read or holds no parameters for the node."""
