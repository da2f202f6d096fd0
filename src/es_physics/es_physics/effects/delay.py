"""Transport delay: the actuator responds to the command of ``delay_s`` earlier.

Plant: the applied voltage is the command delayed, resolved to the plant's internal step.
Calibration: the command is shifted by whole command periods (a zero-order-hold command
makes finer shifts unobservable); a shift of j periods covers delays in (j, j + 1] periods,
so the middle is reported. Feedforward: the set point is predicted ``delay_s`` ahead.
"""

from __future__ import annotations

from typing import ClassVar

from es_physics.effects.base import Effect, FittedEffect, Parameter, Role


class Delay(Effect):
    """Transport delay between command and displacement."""

    name: ClassVar[str] = "delay"
    summary: ClassVar[str] = "transport delay between command and displacement"
    role: ClassVar[Role] = Role.INPUT_SHIFT
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "delay_s", "s", 0.0, 10.0, 2.4e-3, "transport delay (thesis: 12 samples at 5 kHz)"
        ),
    )
    searched: ClassVar[tuple[str, ...]] = ("delay_s",)
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter("delay_s", "s", 0.0, 1.0, 0.0, "delay to predict the set point over (0 = off)"),
    )

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return ``delay_s``: the scanned shift plus half a command period."""
        return {"delay_s": float(fit.values["delay_s"]) + 0.5 * fit.command_period}

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Return the scan's resolution: half a command period."""
        return {"delay_s": 0.5 * fit.command_period}

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Predict the set point over the reported delay."""
        return {"delay_s": reported["delay_s"]}
