"""Deformable-mirror plant simulator: UV heating, thermal network, actuator grid, sensors.

Pure, without rclpy: the simulator (:mod:`.plant` and its parts :mod:`.thermal`,
:mod:`.sensors`, :mod:`.actuators`, :mod:`.effects`, :mod:`.resonance`, :mod:`.reference`),
the scenarios (:mod:`.scenario`), the node's stepping protocol (:mod:`.lockstep`) and
parameters (:mod:`.node_config`) and :mod:`.errors` (every exception class of the
simulator). The ROS node is :mod:`.plant_node`. The orchestration (bring-up, demo,
supervisor, golden runs, reports) is the package es_bringup.
Importing the package is cheap: its modules are loaded on first use (``es_sim_plant.plant``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from es_common.lazy import lazy_modules

if TYPE_CHECKING:  # type checkers see the modules; at run time they load on first access
    from es_sim_plant import (
        actuators,
        effects,
        errors,
        lockstep,
        node_config,
        plant,
        plant_node,
        reference,
        resonance,
        scenario,
        sensors,
        thermal,
    )

#: The public modules of the package.
__all__ = [
    "actuators",
    "effects",
    "errors",
    "lockstep",
    "node_config",
    "plant",
    "plant_node",
    "reference",
    "resonance",
    "scenario",
    "sensors",
    "thermal",
]


# Hidden from type checkers, which then flag a misspelt module instead of accepting any name.
if not TYPE_CHECKING:
    __getattr__ = lazy_modules(__name__, __all__)
