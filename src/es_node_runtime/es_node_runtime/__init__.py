"""What every es_dm node runs on: its ``main()``, its middleware profile and its parameters.

Not the contract (that is :mod:`es_msgs_py`: what goes over the wire and into bags, which a
test stand's own software must match) but how a node of this suite is run: a process's
start-up, signals and teardown, its Fast DDS profile, its parameters declared with ranges and
read back typed, and parameters files every ROS 2 reader types alike. It imports nothing
else of ours.

Importing the package is cheap and needs no rclpy: its modules are loaded on first use.
Pure, without rclpy: :mod:`.param_spec` (what a node parameter accepts, typed parameter
values), :mod:`.param_yaml` (ROS 2 parameters YAML), :mod:`.middleware` (the Fast DDS
profile) and :mod:`.errors`. :mod:`.params` (declare parameters on a node) and
:mod:`.node_main` (``run_node``: the ``main()`` of every node) need rclpy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from es_common.lazy import lazy_modules

if TYPE_CHECKING:  # type checkers see the modules; at run time they load on first access
    from es_node_runtime import (
        errors,
        middleware,
        node_main,
        param_spec,
        param_yaml,
        params,
    )

__version__ = "0.1.0"

#: The public modules of the package.
__all__ = [
    "__version__",
    "errors",
    "middleware",
    "node_main",
    "param_spec",
    "param_yaml",
    "params",
]


# Hidden from type checkers, which then flag a misspelt module instead of accepting any name.
if not TYPE_CHECKING:
    __getattr__ = lazy_modules(__name__, __all__)
