"""Temperature-compensated feedforward: set points -> voltages for the actuator grid.

Pure, without rclpy: :mod:`.feedforward` (the modes), :mod:`.compensation`,
:mod:`.param_file` (configuration <-> parameters and YAML files), :mod:`.node_params` (the
node's declared parameters) and :mod:`.errors` (every exception class of the package). The
calibration that writes its parameters files is the package ``es_calibration``. The ROS node is
:mod:`.feedforward_node`. Importing the package is cheap: its modules are loaded on first
use (``es_feedforward.param_file``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from es_common.lazy import lazy_modules

if TYPE_CHECKING:  # type checkers see the modules; at run time they load on first access
    from es_feedforward import (
        compensation,
        errors,
        feedforward,
        feedforward_config,
        feedforward_node,
        node_params,
        param_file,
    )

#: The public modules of the package.
__all__ = [
    "compensation",
    "errors",
    "feedforward",
    "feedforward_config",
    "feedforward_node",
    "node_params",
    "param_file",
]


# Hidden from type checkers, which then flag a misspelt module instead of accepting any name.
if not TYPE_CHECKING:
    __getattr__ = lazy_modules(__name__, __all__)
