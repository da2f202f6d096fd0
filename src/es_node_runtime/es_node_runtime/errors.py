"""The exception classes of es_node_runtime, in one place (pure: no imports at all).

Each subclasses the builtin it refines, so a generic handler still catches them.

- :class:`ParameterTypeError` (a ``TypeError`` and ``ValueError``): a parameter read back with a
  typed getter of :class:`es_node_runtime.param_spec.ParameterValues` has another type.
- :class:`ParameterValueError`: a node parameter's initial value is not acceptable
  (:func:`es_node_runtime.params.declare_parameters`, the executor choice of
  :mod:`es_node_runtime.node_main`).
"""

from __future__ import annotations

__all__ = ["ParameterTypeError", "ParameterValueError"]


class ParameterTypeError(TypeError, ValueError):
    """A node parameter's value has the wrong type for what reads it (a string for a number).

    A ``TypeError`` by nature, and a ``ValueError`` too: a node that meets it at start-up
    exits with one readable line like for any other invalid parameter.
    """


class ParameterValueError(ValueError):
    """A node parameter's initial value is not acceptable (range, choice or check)."""
