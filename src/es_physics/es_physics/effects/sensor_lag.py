"""Sensor lag: the temperature sensor sits beside the actuator and lags behind it.

Plant: the sensor reads T_s with dT_s/dt = (T_a - T_s) / tau. Calibration: the actuator
leads the sensor, T_a = T_s + tau dT_s/dt. Feedforward: the same lead, its derivative
low-pass filtered (``compensation.temperature_lead_s``, ``temperature_lead_filter_s``); a
calibration sets the filter to LEAD_FILTER_FRACTION of the lag: the lead must follow changes
of the actuator's temperature as fast as the lag hides them, and a shorter filter only
amplifies the sensor's noise (the derivative of a noisy, quantised reading).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, Final

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role
from es_physics.effects.stages import Compensator, PlantContext, PlantStage

#: The lead's derivative filter as a fraction of the calibrated lag.
LEAD_FILTER_FRACTION: Final = 0.5


class SensorLagStage(PlantStage):
    """The sensor's first-order lag (the sensor array applies it)."""

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s

    def sensor_lag_s(self) -> float | None:
        """Return tau [s]."""
        return self.tau_s


class TemperatureLead(Compensator):
    """T_used = T + tau dT/dt with a first-order low-pass on the finite-difference derivative.

    Args:
        tau_s: the lag to undo [s] (0 = pass the temperature through).
        filter_s: time constant of the derivative's low-pass [s].

    """

    def __init__(self, tau_s: float, filter_s: float) -> None:
        self.tau_s = tau_s
        self.filter_s = filter_s
        self._last: tuple[FloatArray, float] | None = None
        self._rate: FloatArray | None = None

    def retuned(self, tau_s: float, filter_s: float) -> TemperatureLead:
        """Return a copy with new parameters and this one's state (this one is unchanged)."""
        other = TemperatureLead(tau_s, filter_s)
        other._last, other._rate = self._last, self._rate
        return other

    def __call__(self, T: FloatArray, t: float) -> FloatArray:
        """Return the lead-corrected temperatures for a sample ``T`` [degC] taken at ``t`` [s]."""
        if self.tau_s == 0.0:
            return T
        if self._last is None or self._rate is None or self._last[0].shape != T.shape:
            self._rate = np.zeros_like(T)
        else:
            T_prev, t_prev = self._last
            dt = t - t_prev
            if dt > 0.0:
                raw = (T - T_prev) / dt
                gain = dt / (dt + self.filter_s)
                rate = self._rate + gain * (raw - self._rate)
                self._rate = np.where(np.isfinite(rate), rate, 0.0)
        self._last = (T, t)
        return np.asarray(T + self.tau_s * self._rate, np.float64)

    def measured_temperature(self, T: FloatArray, t: float) -> FloatArray:
        """Return the lead-corrected temperatures (see :meth:`__call__`)."""
        return self(T, t)


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
        """Lead the measured temperature by the fitted lag, its derivative filtered."""
        return {
            "temperature_lead_s": reported["tau_s"],
            "temperature_lead_filter_s": LEAD_FILTER_FRACTION * reported["tau_s"],
        }

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the sensor's lag."""
        return SensorLagStage(settings["tau_s"])

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the temperature lead, or None when ``temperature_lead_s`` is 0."""
        tau, filter_s = values["temperature_lead_s"], values["temperature_lead_filter_s"]
        if tau == 0.0:
            return None
        if isinstance(previous, TemperatureLead):
            return previous.retuned(tau, filter_s)
        return TemperatureLead(tau, filter_s)
