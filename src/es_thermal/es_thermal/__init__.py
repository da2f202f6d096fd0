"""Per-actuator temperature estimation from noisy, sparse, lagging sensors.

Pure, without rclpy: the estimator (:mod:`.estimator` over :mod:`.lowpass`, :mod:`.kalman`,
:mod:`.modal`, :mod:`.network`, :mod:`.interpolation`, :mod:`.faults`), self-sensing
(:mod:`.selfsensing`, :mod:`.sweep_sync`, :mod:`.resonance_calibration` and its CLI
:mod:`.calibrate_resonance`), :mod:`.evaluation`, the node's parameters and health
(:mod:`.node_params`, :mod:`.resonance_params`, :mod:`.node_health`), the sensor
calibration's parameters file (:mod:`.sensor_params`) and :mod:`.errors`
(every exception class of the package). The ROS node is :mod:`.thermal_node`. Importing the
package is cheap: its modules are loaded on first use (``es_thermal.estimator``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from es_common.lazy import lazy_modules

if TYPE_CHECKING:  # type checkers see the modules; at run time they load on first access
    from es_thermal import (
        calibrate_resonance,
        errors,
        estimator,
        evaluation,
        faults,
        interpolation,
        kalman,
        lowpass,
        modal,
        network,
        node_health,
        node_params,
        resonance_calibration,
        resonance_params,
        selfsensing,
        sensor_params,
        sweep_sync,
        thermal_node,
    )

#: The public modules of the package.
__all__ = [
    "calibrate_resonance",
    "errors",
    "estimator",
    "evaluation",
    "faults",
    "interpolation",
    "kalman",
    "lowpass",
    "modal",
    "network",
    "node_health",
    "node_params",
    "resonance_calibration",
    "resonance_params",
    "selfsensing",
    "sensor_params",
    "sweep_sync",
    "thermal_node",
]


# Hidden from type checkers, which then flag a misspelt module instead of accepting any name.
if not TYPE_CHECKING:
    __getattr__ = lazy_modules(__name__, __all__)
