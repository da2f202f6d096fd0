"""Declare ROS parameters with descriptors, ranges and validation on set.

rclpy itself rejects a value outside a declared ``FloatingPointRange``/``IntegerRange`` when
it is set at run time; :class:`ParameterSpec` adds choices and custom checks and gives the
same readable reason for all of them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

Scalar = bool | int | float | str
Check = Callable[[object], str | None]


@dataclass(frozen=True)
class ParameterSpec:
    """One declared parameter: default, description and what values it accepts.

    ``low``/``high`` give an inclusive numeric range, ``choices`` a set of allowed strings,
    ``check`` any further test returning a reason string when the value is rejected.
    """

    name: str
    default: Scalar | list[float] | list[int] | list[str]
    description: str
    low: float | None = None
    high: float | None = None
    choices: Sequence[str] = ()
    check: Check | None = None
    read_only: bool = False
    dynamic_typing: bool = False
    extra: dict[str, str] = field(default_factory=dict)

    def descriptor(self) -> ParameterDescriptor:
        """Return the ``ParameterDescriptor`` announced for this parameter."""
        text = self.description
        if self.choices:
            text += f" One of: {', '.join(self.choices)}."
        desc = ParameterDescriptor(
            description=text, read_only=self.read_only, dynamic_typing=self.dynamic_typing
        )
        if self.low is not None and self.high is not None:
            if isinstance(self.default, bool) or not isinstance(self.default, int | float):
                pass
            elif isinstance(self.default, int):
                desc.integer_range = [
                    IntegerRange(from_value=int(self.low), to_value=int(self.high), step=0)
                ]
            else:
                desc.floating_point_range = [
                    FloatingPointRange(
                        from_value=float(self.low), to_value=float(self.high), step=0.0
                    )
                ]
        return desc

    def reason_to_reject(self, value: object) -> str | None:
        """Return why ``value`` is not acceptable, or ``None`` when it is."""
        if self.choices and value not in self.choices:
            return f"{self.name}={value!r} is not one of {list(self.choices)}"
        numeric = isinstance(value, int | float) and not isinstance(value, bool)
        in_range = (
            not numeric or self.low is None or self.high is None or self.low <= value <= self.high  # type: ignore[operator]
        )
        if not in_range:
            return f"{self.name}={value!r} is outside [{self.low}, {self.high}]"
        if self.check is not None:
            return self.check(value)
        return None


def declare_parameters(node: Node, specs: Sequence[ParameterSpec]) -> dict[str, object]:
    """Declare ``specs`` on ``node``, validate the initial values and guard later sets.

    Returns:
        The initial value of every parameter by name.

    Raises:
        ValueError: an initial value (from the command line or a parameters file) is not
            acceptable; the message gives the reason.

    """
    by_name = {spec.name: spec for spec in specs}
    values: dict[str, object] = {}
    for spec in specs:
        try:
            param = node.declare_parameter(spec.name, spec.default, spec.descriptor())
        except ParameterException as err:  # rclpy's own range check of an initial value
            raise ValueError(f"invalid parameter {spec.name}: {err}") from None
        values[spec.name] = param.value
        reason = spec.reason_to_reject(param.value)
        if reason is not None:
            raise ValueError(f"invalid parameter: {reason}")

    def on_set(params: list[Parameter]) -> SetParametersResult:
        for param in params:
            spec = by_name.get(param.name)
            reason = spec.reason_to_reject(param.value) if spec is not None else None
            if reason is not None:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
    return values
