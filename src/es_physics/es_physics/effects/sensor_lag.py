"""Sensor lag: the temperature sensor sits beside the actuator and lags behind it.

Plant: the sensor reads T_s with dT_s/dt = (T_a - T_s) / tau. Calibration: the actuator
leads the sensor, T_a = T_s + tau dT_s/dt. Feedforward: the same lead, its derivative
low-pass filtered (``compensation.temperature_lead_s``, ``temperature_lead_filter_s``).
"""

from __future__ import annotations

from typing import ClassVar

from es_physics.effects.base import Effect, FittedEffect, Parameter, Role


class SensorLag(Effect):
    """First-order lag of the temperature sensor behind the actuator."""

    name: ClassVar[str] = "sensor_lag"
    summary: ClassVar[str] = "temperature sensor lags the actuator (first order, time constant tau)"
    role: ClassVar[Role] = Role.TEMPERATURE
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "tau_s", "s", 0.0, 1e9, 5.0, "sensor time constant", low_open=True, time_scaled=True
        ),
    )
    fit_parameters: ClassVar[tuple[str, ...]] = ("tau_s",)
    local_options: ClassVar[tuple[str, ...]] = ("tau_s",)
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter("temperature_lead_s", "s", 0.0, 3600.0, 0.0, "sensor lag to undo (0 = off)"),
        Parameter(
            "temperature_lead_filter_s", "s", 0.0, 3600.0, 0.5, "low-pass of the lead's dT/dt"
        ),
    )

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return ``tau_s`` [s]."""
        return {"tau_s": float(fit.values["tau_s"])}

    def problem(self, reported: dict[str, float]) -> str | None:
        """Reject a lag <= 0."""
        if reported["tau_s"] <= 0:
            return f"lag {reported['tau_s']:.3g} s is not positive"
        return None

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Lead the measured temperature by the fitted lag."""
        return {"temperature_lead_s": reported["tau_s"]}
