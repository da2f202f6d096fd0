"""The es_dm interface contract in code: topics, QoS, array layouts, diagnostics and bags.

See ``shared/docs/interfaces.md``; every node and tool of the suite goes through this package
so that data from a real test stand can replace the simulator at any point.

Importing the package is cheap and needs no rclpy: its modules are loaded on first use
(``es_msgs_py.bag`` or ``from es_msgs_py import bag``). Pure, without rclpy: :mod:`.bag`
(bag I/O, needs rosbags and numpy), :mod:`.topic_names` (the contract's topic names) and
:mod:`.errors` (every exception class of the package). The others need rclpy or the ROS
message packages: :mod:`.arrays` (message classes), :mod:`.topics`, :mod:`.diagnostics`.
What every node runs on (``run_node``, the middleware profile, parameters) is the package
``es_node_runtime``; the recorder and the lab importer are the package ``es_recordings``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from es_common.lazy import lazy_modules

if TYPE_CHECKING:  # type checkers see the modules; at run time they load on first access
    from es_msgs_py import (
        arrays,
        bag,
        diagnostics,
        errors,
        topic_names,
        topics,
    )

__version__ = "0.1.0"

#: The public modules of the package.
__all__ = [
    "__version__",
    "arrays",
    "bag",
    "diagnostics",
    "errors",
    "topic_names",
    "topics",
]


# Hidden from type checkers, which then flag a misspelt module instead of accepting any name.
if not TYPE_CHECKING:
    __getattr__ = lazy_modules(__name__, __all__)
