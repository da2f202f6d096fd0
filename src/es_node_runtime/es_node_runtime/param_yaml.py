"""ROS 2 parameters YAML that every reader types alike (pure: no rclpy).

YAML 1.1, which PyYAML implements, reads a float only with a dot: ``-4e-17`` and ``1e-07``
are *strings* to it, ``-4.0e-17`` and ``1.0e-07`` are floats. Worse, rclpy's
``parameter_dict_from_yaml_file`` (what ``ros2 param load`` uses) turns every value it read
back into text with ``str()`` and reads that again as YAML: a float whose Python ``repr``
has no dot (``1e-07``, ``-4e-17``, ``1e+20``) becomes a string there whatever the file
said, and loading fails with "expected DOUBLE_ARRAY got STRING_ARRAY". rcl's own parser
(``--params-file``) reads both forms.

:func:`dump_parameters` therefore writes every float with a dot, and a float whose shortest
``repr`` has none as its neighbour one unit in the last place towards zero (``1e-07`` ->
``9.999999999999999e-08``, a relative change of about 1e-16), whose ``repr`` has a dot: the
file then loads as doubles through ``--params-file``, ``ros2 param load`` and PyYAML alike.
:func:`floats_from_strings` reads dot-less exponent strings back as the floats they stand
for (files written by other tools, e.g. ``ros2 param dump``).
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Mapping
from typing import Final

import yaml

#: A number in exponent form without a dot (``-4e-17``): a string to YAML 1.1.
_DOTLESS_FLOAT: Final = re.compile(r"^[-+]?[0-9]+[eE][-+]?[0-9]+$")


class _Dumper(yaml.SafeDumper):
    """SafeDumper whose floats always carry a dot, also in ``str(value)`` (see above)."""


def _represent_float(dumper: yaml.SafeDumper, value: float) -> yaml.ScalarNode:
    if math.isnan(value):
        text = ".nan"
    elif math.isinf(value):
        text = ".inf" if value > 0 else "-.inf"
    else:
        text = repr(float(value))
        # 1e-07: see the module docstring (subnormals away from zero, never to 0)
        towards = 0.0 if abs(value) >= sys.float_info.min else math.copysign(math.inf, value)
        while "." not in text:
            value = math.nextafter(value, towards)
            text = repr(value)
    return dumper.represent_scalar("tag:yaml.org,2002:float", text.lower())


_Dumper.add_representer(float, _represent_float)


def dump_parameters(document: Mapping[str, object]) -> str:
    """Return ``document`` as YAML text whose floats every ROS 2 reader reads as floats.

    Raises:
        yaml.representer.RepresenterError: a value YAML cannot represent (e.g. numpy types).

    """
    return yaml.dump(dict(document), Dumper=_Dumper, sort_keys=False)


def floats_from_strings(tree: object) -> tuple[object, list[str]]:
    """Return ``tree`` with dot-less exponent strings (``"-4e-17"``) turned into floats.

    Works through nested mappings and lists; returns the converted tree and the dotted
    names (``law.m1``) of what was converted, so a caller can say so.
    """
    converted: list[str] = []

    def convert(value: object, name: str) -> object:
        if isinstance(value, Mapping):
            return {k: convert(v, f"{name}.{k}" if name else str(k)) for k, v in value.items()}
        if isinstance(value, list):
            return [convert(v, name) for v in value]
        if isinstance(value, str) and _DOTLESS_FLOAT.match(value.strip()):
            if name not in converted:
                converted.append(name)
            return float(value)
        return value

    return convert(tree, ""), converted
