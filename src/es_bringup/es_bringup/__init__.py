"""Bring-up and evaluation of the es_dm graph: launch, supervisor, demo and its report.

The top layer: it imports every other package and nothing of ours imports it (tests and
bench do). Pure, without rclpy: the graph description (:mod:`.graph`), the calibration's files and
which node undoes the sensor lag (:mod:`.calibration_files`), the supervisor
(:mod:`.supervisor`), the evaluation of recorded runs (:mod:`.metrics`, :mod:`.invariants`,
:mod:`.analysis`, :mod:`.goal`, :mod:`.report`, :mod:`.selfsensing_study`) and
:mod:`.errors`. Executables: :mod:`.bringup`, :mod:`.demo` (with its ``demo_*`` parts),
:mod:`.golden`, :mod:`.selfsensing_demo`; the launch file ``closed_loop.launch.py``.
Importing the package is cheap: its modules are loaded on first use (``es_bringup.graph``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from es_common.lazy import lazy_modules

if TYPE_CHECKING:  # type checkers see the modules; at run time they load on first access
    from es_bringup import (
        analysis,
        bringup,
        calibration_files,
        demo,
        errors,
        goal,
        golden,
        graph,
        invariants,
        metrics,
        report,
        selfsensing_demo,
        selfsensing_study,
        supervisor,
    )

#: The public modules of the package.
__all__ = [
    "analysis",
    "bringup",
    "calibration_files",
    "demo",
    "errors",
    "goal",
    "golden",
    "graph",
    "invariants",
    "metrics",
    "report",
    "selfsensing_demo",
    "selfsensing_study",
    "supervisor",
]


# Hidden from type checkers, which then flag a misspelt module instead of accepting any name.
if not TYPE_CHECKING:
    __getattr__ = lazy_modules(__name__, __all__)
