"""What a node parameter accepts, and the declared values read back with their types (pure).

:class:`ParameterSpec` states one parameter (default, description with its unit, range,
choices, custom check); :class:`ParameterValues` holds the values a node declared and hands
them out typed (``values.get_float("time_scale")``), so the modules that map parameters to a
configuration are checked by mypy and tested without ROS. :mod:`es_node_runtime.params` declares
the specs on a node and returns a :class:`ParameterValues`.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from numbers import Integral, Real
from typing import overload

from es_node_runtime.errors import ParameterTypeError

__all__ = ["Check", "ParameterSpec", "ParameterValues", "Scalar"]

Scalar = bool | int | float | str
Check = Callable[[object], str | None]

_MISSING = object()


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

    def full_description(self) -> str:
        """Return the description announced for the parameter (with its choices, if any)."""
        text = self.description
        if self.choices:
            text += f" One of: {', '.join(self.choices)}."
        return text

    def reason_to_reject(self, value: object) -> str | None:
        """Return why ``value`` is not acceptable, or ``None`` when it is."""
        if self.choices and value not in self.choices:
            return f"{self.name}={value!r} is not one of {list(self.choices)}"
        if (
            isinstance(value, int | float)
            and not isinstance(value, bool)
            and self.low is not None
            and self.high is not None
            and not self.low <= value <= self.high
        ):
            return f"{self.name}={value!r} is outside [{self.low}, {self.high}]"
        if self.check is not None:
            return self.check(value)
        return None


class ParameterValues(Mapping[str, object]):
    """Parameter values by name, read back typed.

    A read-only mapping (``values["x"]`` gives the raw value) with typed getters that check
    the value's type: ``get_float``, ``get_int``, ``get_bool``, ``get_str``, ``get_floats``
    and ``get_strs``. A getter given a ``default`` returns it when the name is absent.
    Integers pass as floats (a YAML ``150`` for a double); booleans never pass as numbers.
    """

    def __init__(self, values: Mapping[str, object]) -> None:
        self._values = dict(values)

    def __getitem__(self, name: str) -> object:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __repr__(self) -> str:
        return f"ParameterValues({self._values!r})"

    def _raw(self, name: str, default: object) -> object:
        if name in self._values:
            return self._values[name]
        if default is _MISSING:
            raise KeyError(name)
        return default

    @overload
    def get_float(self, name: str) -> float: ...
    @overload
    def get_float(self, name: str, default: float) -> float: ...
    def get_float(self, name: str, default: object = _MISSING) -> float:
        """Return parameter ``name`` as a float.

        Raises:
            KeyError: ``name`` is absent and no ``default`` was given.
            ParameterTypeError: the value is no real number (a bool, a string, a list).

        """
        value = self._raw(name, default)
        if isinstance(value, bool) or not isinstance(value, Real):
            raise ParameterTypeError(f"parameter {name}={value!r} is not a number")
        return float(value)

    @overload
    def get_int(self, name: str) -> int: ...
    @overload
    def get_int(self, name: str, default: int) -> int: ...
    def get_int(self, name: str, default: object = _MISSING) -> int:
        """Return parameter ``name`` as an int (a float with an integral value passes).

        Raises:
            KeyError: ``name`` is absent and no ``default`` was given.
            ParameterTypeError: the value is no integer.

        """
        value = self._raw(name, default)
        if isinstance(value, Integral) and not isinstance(value, bool):
            return int(value)
        if isinstance(value, Real) and not isinstance(value, bool) and float(value).is_integer():
            return int(float(value))
        raise ParameterTypeError(f"parameter {name}={value!r} is not an integer")

    def get_bool(self, name: str) -> bool:
        """Return parameter ``name`` as a bool.

        Raises:
            KeyError: ``name`` is absent.
            ParameterTypeError: the value is no bool.

        """
        value = self._raw(name, _MISSING)
        if not isinstance(value, bool):
            raise ParameterTypeError(f"parameter {name}={value!r} is not a bool")
        return value

    @overload
    def get_str(self, name: str) -> str: ...
    @overload
    def get_str(self, name: str, default: str) -> str: ...
    def get_str(self, name: str, default: object = _MISSING) -> str:
        """Return parameter ``name`` as a string.

        Raises:
            KeyError: ``name`` is absent and no ``default`` was given.
            ParameterTypeError: the value is no string.

        """
        value = self._raw(name, default)
        if not isinstance(value, str):
            raise ParameterTypeError(f"parameter {name}={value!r} is not a string")
        return value

    def get_floats(self, name: str) -> list[float]:
        """Return array parameter ``name`` as a list of floats (an untyped empty array: ``[]``).

        Raises:
            KeyError: ``name`` is absent.
            ParameterTypeError: the value is no sequence of real numbers.

        """
        value = self._raw(name, _MISSING)
        if isinstance(value, bytes | bytearray) and not value:
            return []  # rclpy's untyped empty array
        if isinstance(value, str | bytes | bytearray) or not isinstance(value, Collection):
            raise ParameterTypeError(f"parameter {name}={value!r} is not an array of numbers")
        items = list(value)
        if not all(isinstance(v, Real) and not isinstance(v, bool) for v in items):
            raise ParameterTypeError(f"parameter {name}={value!r} is not an array of numbers")
        return [float(v) for v in items]

    def get_strs(self, name: str) -> list[str]:
        """Return array parameter ``name`` as a list of strings (an untyped empty array: ``[]``).

        Raises:
            KeyError: ``name`` is absent.
            ParameterTypeError: the value is no sequence of strings.

        """
        value = self._raw(name, _MISSING)
        if isinstance(value, bytes | bytearray) and not value:
            return []
        if isinstance(value, str | bytes | bytearray) or not isinstance(value, Collection):
            raise ParameterTypeError(f"parameter {name}={value!r} is not an array of strings")
        items = list(value)
        if not all(isinstance(v, str) for v in items):
            raise ParameterTypeError(f"parameter {name}={value!r} is not an array of strings")
        return items

