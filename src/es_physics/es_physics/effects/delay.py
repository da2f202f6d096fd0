"""Transport delay: the actuator responds to the command of ``delay_s`` earlier.

Plant: the applied voltage is the command delayed, resolved to the plant's internal step.
Calibration: the command shifted by j + f command periods, interpolated between the
commands in effect j and j + 1 periods earlier, (1 - f) u_j + f u_(j+1) (a fractional delay;
f scanned in steps of 0.05, so the resolution is 0.05 command periods); the shift is
reported. Feedforward: the set point is predicted ``delay_s`` ahead.
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
        """Return ``delay_s``: the scanned shift [s]."""
        return {"delay_s": float(fit.values["delay_s"])}

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Return half the scan's step, 0.025 command periods [s]."""
        return {"delay_s": 0.025 * fit.command_period}

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Predict the set point over the reported delay."""
        return {"delay_s": reported["delay_s"]}
