"""Electrostrictive actuator physics shared by plant, feedforward and calibration.

No ROS here: parameters and their temperature laws (:mod:`.params`), the displacement models
and their inverses (:mod:`.laws`), the effects beyond the basic law with their registry
(:mod:`.effects`), the mirror's per-cell thermal parameters shared by the simulator and the
estimator (:mod:`.thermal_network`) and every exception class of the package
(:mod:`.errors`). Importing the package is cheap: its modules are loaded on first use
(``es_physics.laws``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from es_common.lazy import lazy_modules

if TYPE_CHECKING:  # type checkers see the modules; at run time they load on first access
    from es_physics import (
        effects,
        errors,
        laws,
        params,
        thermal_network,
    )

__version__ = "0.1.0"

#: The public modules of the package.
__all__ = [
    "__version__",
    "effects",
    "errors",
    "laws",
    "params",
    "thermal_network",
]


# Hidden from type checkers, which then flag a misspelt module instead of accepting any name.
if not TYPE_CHECKING:
    __getattr__ = lazy_modules(__name__, __all__)
