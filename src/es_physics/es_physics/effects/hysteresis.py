"""Hysteresis: a play operator blended with the drive, growing towards Tm.

V_eff = (1 - a) V + a play_r(V), a = weight exp(-(T_a - T_0) / HYSTERESIS_DECAY). The plant
takes T_0 = Tm + HYSTERESIS_ONSET (``weight`` is a there, clipped to [0, 1]); the calibration
takes T_0 = the data's mean temperature (``weight`` is a there). Feedforward: the analytic
inverse of the blend with a per-actuator play state (``compensation.hysteresis_*``).
"""

from __future__ import annotations

from typing import ClassVar, Final

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role

#: Hysteresis weight a = a0 exp(-(T_a - Tm - HYSTERESIS_ONSET) / HYSTERESIS_DECAY) [degC].
HYSTERESIS_ONSET: Final = 2.0
HYSTERESIS_DECAY: Final = 4.0


def hysteresis_weight(T: FloatArray, Tm: float | FloatArray, weight: float) -> FloatArray:
    """Return a = weight exp(-(T - Tm - 2) / 4), clipped to [0, 1] (T, Tm [degC])."""
    a = weight * np.exp(-(T - Tm - HYSTERESIS_ONSET) / HYSTERESIS_DECAY)
    return np.asarray(np.clip(a, 0.0, 1.0), np.float64)


def play(previous: FloatArray, V: FloatArray, threshold: float) -> FloatArray:
    """Return the backlash (play) operator output for input V [V] given its previous output."""
    return np.asarray(np.clip(previous, V - threshold, V + threshold), np.float64)


class Hysteresis(Effect):
    """Play-operator hysteresis on the drive voltage."""

    name: ClassVar[str] = "hysteresis"
    summary: ClassVar[str] = "play operator (half-width r) blended with the drive, weight a(T)"
    role: ClassVar[Role] = Role.PLAY
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = (
        Parameter("weight", "", 0.0, 1.0, 0.1, "blend weight a at Tm + 2 degC"),
        Parameter("threshold_v", "V", 0.0, 1e4, 30.0, "play operator half-width r"),
    )
    fit_parameters: ClassVar[tuple[str, ...]] = ("weight",)
    searched: ClassVar[tuple[str, ...]] = ("threshold_v",)
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter("hysteresis_weight", "", 0.0, 0.9, 0.0, "play weight a (0 = off)"),
        Parameter("hysteresis_threshold_v", "V", 0.0, 1000.0, 0.0, "play half-width r"),
    )

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return ``weight`` and ``threshold_v`` [V]."""
        return {
            "weight": float(fit.values["weight"]),
            "threshold_v": float(fit.values["threshold_v"]),
        }

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Return the weight's uncertainty (the threshold is scanned)."""
        return {"weight": float(fit.sigma["weight"])}

    def problem(self, reported: dict[str, float]) -> str | None:
        """Reject a blend weight outside (0, 1)."""
        if not 0.0 < reported["weight"] < 1.0:
            return f"weight {reported['weight']:.3g} outside (0, 1)"
        return None

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Invert the fitted blend."""
        return {
            "hysteresis_weight": reported["weight"],
            "hysteresis_threshold_v": reported["threshold_v"],
        }
