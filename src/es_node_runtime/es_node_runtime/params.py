"""Declare ROS parameters with descriptors, ranges and validation on set.

rclpy itself rejects a value outside a declared ``FloatingPointRange``/``IntegerRange`` when
it is set at run time; :class:`ParameterSpec` (:mod:`es_node_runtime.param_spec`, pure) adds
choices and custom checks and gives the same readable reason for all of them.
:func:`declare_parameters` returns the initial values as a typed
:class:`~es_node_runtime.param_spec.ParameterValues`.
"""

from __future__ import annotations

from collections.abc import Sequence

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

from es_node_runtime.errors import ParameterValueError
from es_node_runtime.param_spec import Check, ParameterSpec, ParameterValues, Scalar

__all__ = [
    "Check",
    "ParameterSpec",
    "ParameterValues",
    "Scalar",
    "declare_parameters",
    "descriptor",
]


def descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    """Return the ``ParameterDescriptor`` announced for ``spec`` (description, range, flags)."""
    desc = ParameterDescriptor(
        description=spec.full_description(),
        read_only=spec.read_only,
        dynamic_typing=spec.dynamic_typing,
    )
    if spec.low is not None and spec.high is not None:
        if isinstance(spec.default, bool) or not isinstance(spec.default, int | float):
            pass
        elif isinstance(spec.default, int):
            desc.integer_range = [
                IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=0)
            ]
        else:
            desc.floating_point_range = [
                FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high), step=0.0)
            ]
    return desc


def declare_parameters(node: Node, specs: Sequence[ParameterSpec]) -> ParameterValues:
    """Declare ``specs`` on ``node``, validate the initial values and guard later sets.

    Returns:
        The initial value of every parameter by name, with typed getters.

    Raises:
        ValueError: an initial value (from the command line or a parameters file) is not
            acceptable; the message gives the reason.

    """
    by_name = {spec.name: spec for spec in specs}
    values: dict[str, object] = {}
    for spec in specs:
        try:
            param = node.declare_parameter(spec.name, spec.default, descriptor(spec))
        except ParameterException as err:  # rclpy's own range check of an initial value
            raise ParameterValueError(f"invalid parameter {spec.name}: {err}") from None
        values[spec.name] = param.value
        reason = spec.reason_to_reject(param.value)
        if reason is not None:
            raise ParameterValueError(f"invalid parameter: {reason}")

    def on_set(params: list[Parameter]) -> SetParametersResult:
        for param in params:
            spec = by_name.get(param.name)
            reason = spec.reason_to_reject(param.value) if spec is not None else None
            if reason is not None:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
    return ParameterValues(values)
