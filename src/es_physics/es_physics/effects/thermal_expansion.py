"""Thermal expansion: a voltage-independent displacement proportional to the temperature.

z += alpha (T_a - T_ref). Calibration: alpha (T_a - T_mean) + offset, an additive term;
T_ref = T_mean - offset / alpha is reported. Feedforward: alpha (T - T_ref) is subtracted
from the set point (``compensation.thermal_expansion``, ``expansion_reference_temperature``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from es_physics.effects.base import Additive, Effect, FittedEffect, FloatArray, Parameter, Role
from es_physics.effects.identifiable import Identifiable
from es_physics.effects.stages import Compensator, PlantContext, PlantStage, StepState


class ExpansionStage(PlantStage):
    """z += alpha (T_a - T_ref), T_ref the run's initial base temperature."""

    def __init__(self, alpha: float) -> None:
        self.alpha = alpha

    def displacement(self, z: FloatArray, step: StepState) -> FloatArray:
        """Return z + alpha (T_a - T_ref)."""
        return np.asarray(z + self.alpha * (step.T - step.reference_temperature), np.float64)


class ExpansionCompensation(Compensator):
    """alpha (T - T_ref) subtracted from the set point."""

    def __init__(self, alpha: float, reference_temperature: float) -> None:
        self.alpha, self.reference_temperature = alpha, reference_temperature

    def setpoint(self, z: FloatArray, T: FloatArray, t: float) -> FloatArray:
        """Return z - alpha (T - T_ref)."""
        return np.asarray(z - self.alpha * (T - self.reference_temperature), np.float64)


class ThermalExpansion(Effect):
    """Thermal expansion of the actuator stack."""

    name: ClassVar[str] = "thermal_expansion"
    summary: ClassVar[str] = "displacement proportional to temperature, independent of voltage"
    role: ClassVar[Role] = Role.ADDITIVE
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = (
        # 2e-6 /degC (PMN-PT 1.6-3.2e-6) over L = 0.2 mm
        Parameter("alpha_m_per_degc", "m/degC", -1e-6, 1e-6, 0.4e-9, "expansion coefficient"),
    )
    fit_parameters: ClassVar[tuple[str, ...]] = ("alpha_m_per_degc", "offset_m")
    identifiable: ClassVar[Mapping[str, Identifiable]] = {
        "reference_temperature": Identifiable.INSIDE_TEMPERATURE_RANGE
    }
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter("thermal_expansion", "m/degC", -1e-8, 1e-8, 0.0, "expansion alpha (0 = off)"),
        Parameter(
            "expansion_reference_temperature", "degC", -50.0, 150.0, 46.0, "zero expansion at"
        ),
    )

    def additive(self, g: Mapping[str, float], t: FloatArray, Ta: FloatArray) -> Additive:
        """Return alpha (T_a - T_mean) + offset and its derivatives."""
        alpha = g["alpha_m_per_degc"]
        return Additive(alpha * Ta + g["offset_m"], (Ta, np.ones(1)), alpha)

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return ``alpha_m_per_degc`` and ``reference_temperature`` [degC]."""
        alpha = float(fit.values["alpha_m_per_degc"])
        offset = float(fit.values["offset_m"])
        ref = fit.mean_temperature - offset / alpha if alpha else 0.0
        return {"alpha_m_per_degc": alpha, "reference_temperature": ref}

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Return alpha's uncertainty."""
        return {"alpha_m_per_degc": float(fit.sigma["alpha_m_per_degc"])}

    def problem(self, reported: dict[str, float]) -> str | None:
        """Accept any sign (a stand's set-up may contract)."""
        return None

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Subtract the fitted expansion."""
        return {
            "thermal_expansion": reported["alpha_m_per_degc"],
            "expansion_reference_temperature": reported["reference_temperature"],
        }

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the expansion term."""
        return ExpansionStage(settings["alpha_m_per_degc"])

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the expansion's subtraction, or None when alpha is 0."""
        if values["thermal_expansion"] == 0.0:
            return None
        return ExpansionCompensation(
            values["thermal_expansion"], values["expansion_reference_temperature"]
        )
