"""Aging drift: M_eff(t) = M(T) (1 - a (1 - exp(-(t / tau)^nu))), t from the start of the run.

Calibration: a gain on the law's displacement, with ``log_tau_s`` and ``log_nu`` as unknowns
(nu kept within exp(+-DRIFT_LOG_NU_LIMIT)). Feedforward: the set point is divided by the
same factor (``compensation.drift_*``, with the data's start as epoch).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, Final

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role
from es_physics.effects.stages import Compensator, PlantContext, PlantStage, StepState

#: The drift exponent nu is kept within exp(+-DRIFT_LOG_NU_LIMIT) by the calibration.
DRIFT_LOG_NU_LIMIT: Final = float(np.log(5.0))
#: Drift time constants tried by the calibration, as fractions of the record's duration.
DRIFT_TAU_FRACTIONS: Final = (0.05, 0.25, 1.0)


def drift_factor(t: FloatArray | float, fraction: float, tau_s: float, nu: float) -> FloatArray:
    """Return M_eff / M = 1 - a (1 - exp(-(t / tau)^nu)) at run time(s) t >= 0 [s]."""
    tt = np.maximum(np.asarray(t, np.float64), 0.0)
    return np.asarray(1.0 - fraction * (1.0 - np.exp(-((tt / tau_s) ** nu))), np.float64)


def compensated_drift(t: float, fraction: float, tau_s: float, nu: float, epoch_s: float) -> float:
    """Return M_eff / M = 1 - a (1 - exp(-(t_rel / tau)^nu)), t_rel = max(t - epoch, 0) [s]."""
    if fraction == 0.0:
        return 1.0
    t_rel = max(t - epoch_s, 0.0)
    decay = float(np.exp(-((t_rel / tau_s) ** nu)))
    return 1.0 - fraction * (1.0 - decay)


class DriftStage(PlantStage):
    """The law's displacement times the drift factor at the run time."""

    def __init__(self, fraction: float, tau_s: float, nu: float) -> None:
        self.fraction, self.tau_s, self.nu = fraction, tau_s, nu

    def displacement(self, z: FloatArray, step: StepState) -> FloatArray:
        """Return z (1 - a (1 - exp(-(t / tau)^nu)))."""
        factor = drift_factor(step.times, self.fraction, self.tau_s, self.nu)
        return np.asarray(z * factor[:, None, None], np.float64)


class DriftCompensation(Compensator):
    """The set point divided by the drift factor (t = ROS time - epoch)."""

    def __init__(self, fraction: float, tau_s: float, nu: float, epoch_s: float) -> None:
        self.fraction, self.tau_s, self.nu, self.epoch_s = fraction, tau_s, nu, epoch_s

    def setpoint(self, z: FloatArray, T: FloatArray, t: float) -> FloatArray:
        """Return z / (1 - a (1 - exp(-(t_rel / tau)^nu)))."""
        factor = compensated_drift(t, self.fraction, self.tau_s, self.nu, self.epoch_s)
        return z / factor if factor != 1.0 else z


class Drift(Effect):
    """Aging of the electrostrictive coefficient."""

    name: ClassVar[str] = "drift"
    summary: ClassVar[str] = "aging: M falls by a fraction a with a stretched exponential"
    role: ClassVar[Role] = Role.GAIN
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = (
        Parameter("fraction", "", 0.0, 1.0, 0.03, "final relative loss a of M", high_open=True),
        Parameter("tau_s", "s", 0.0, 1e12, 300.0, "time constant", low_open=True, time_scaled=True),
        Parameter("nu", "", 0.0, 100.0, 0.5, "stretching exponent", low_open=True),
    )
    fit_parameters: ClassVar[tuple[str, ...]] = ("fraction", "log_tau_s", "log_nu")
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter("drift_fraction", "", 0.0, 0.5, 0.0, "final relative loss a (0 = off)"),
        Parameter("drift_tau_s", "s", 1e-3, 1e9, 3600.0, "time constant tau"),
        Parameter("drift_nu", "", 0.05, 5.0, 1.0, "stretching exponent nu"),
        Parameter("drift_epoch_s", "s", 0.0, 1e12, 0.0, "ROS time at which the drift started"),
    )

    def starts(self, duration_s: float) -> list[dict[str, float]]:
        """Start from a small fraction (so the nonlinear terms have gradients), several taus."""
        return [
            {"fraction": 0.01, "log_tau_s": float(np.log(f * duration_s)), "log_nu": 0.0}
            for f in DRIFT_TAU_FRACTIONS
        ]

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return ``fraction``, ``tau_s`` [s] and ``nu``."""
        return {
            "fraction": float(fit.values["fraction"]),
            "tau_s": float(np.exp(fit.values["log_tau_s"])),
            "nu": float(np.exp(fit.values["log_nu"])),
        }

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Propagate the log-parameters' uncertainties."""
        return {
            "fraction": float(fit.sigma["fraction"]),
            "tau_s": float(np.exp(fit.values["log_tau_s"])) * float(fit.sigma["log_tau_s"]),
            "nu": float(np.exp(fit.values["log_nu"])) * float(fit.sigma["log_nu"]),
        }

    def problem(self, reported: dict[str, float]) -> str | None:
        """Reject a fraction outside (-1, 1)."""
        if not abs(reported["fraction"]) < 1.0:
            return f"fraction {reported['fraction']:.3g} outside (-1, 1)"
        return None

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Divide by the fitted drift from the data's start on."""
        return {
            "drift_fraction": reported["fraction"],
            "drift_tau_s": reported["tau_s"],
            "drift_nu": reported["nu"],
            "drift_epoch_s": start_time,
        }

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the gain loss over the run."""
        return DriftStage(settings["fraction"], settings["tau_s"], settings["nu"])

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the set point's division by the drift, or None when the fraction is 0."""
        if values["drift_fraction"] == 0.0:
            return None
        return DriftCompensation(
            values["drift_fraction"],
            values["drift_tau_s"],
            values["drift_nu"],
            values["drift_epoch_s"],
        )
