"""M(T) / k(T) curvature: quadratic T* terms m3, k3 in the laws of M and k.

Plant: m3, k3 are added to every actuator's. Calibration: two more per-actuator law
coefficients; the grid's medians are reported. Feedforward: the parameter file's m3, k3.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import ClassVar

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, Parameter, Role
from es_physics.effects.stages import PlantContext, PlantStage
from es_physics.params import ActuatorParams


class CurvatureStage(PlantStage):
    """m3, k3 added to the actuators' nominal law coefficients."""

    def __init__(self, m3: float, k3: float) -> None:
        self.m3, self.k3 = m3, k3

    def law(self, params: ActuatorParams) -> ActuatorParams:
        """Return the coefficients with the curvature added."""
        return replace(params, m3=params.m3 + self.m3, k3=params.k3 + self.k3)


class TemperatureCurvature(Effect):
    """Quadratic temperature terms of the laws of M and k."""

    name: ClassVar[str] = "temperature_curvature"
    summary: ClassVar[str] = "M(T*) and k(T*) bend: quadratic terms m3, k3"
    role: ClassVar[Role] = Role.LAW
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = (
        Parameter("m3", "m^2/V^2/degC^2", -1e-15, 1e-15, 1.0e-18, "quadratic term of M"),
        Parameter("k3", "m/V/degC^2", -1e-6, 1e-6, 0.3e-9, "quadratic term of k"),
    )
    local_parameters: ClassVar[tuple[str, ...]] = ("m3", "k3")

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return the grid's median ``m3`` and ``k3``."""
        return {k: float(np.median(fit.local[k])) for k in self.local_parameters}

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Return the grid's median uncertainties."""
        return {k: float(np.median(fit.local_sigma[k])) for k in self.local_parameters}

    def problem(self, reported: dict[str, float]) -> str | None:
        """Accept any curvature."""
        return None

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the law's curvature (the feedforward reads it from ``law.m3``/``law.k3``)."""
        return CurvatureStage(settings["m3"], settings["k3"])
