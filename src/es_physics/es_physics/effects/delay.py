"""Transport delay: the actuator responds to the command of ``delay_s`` earlier.

Plant: the applied voltage is the command delayed, resolved to the plant's internal step.
Calibration: the command shifted by j + f command periods, interpolated between the
commands in effect j and j + 1 periods earlier, (1 - f) u_j + f u_(j+1) (a fractional delay;
f scanned in steps of 0.05, so the resolution is 0.05 command periods); the shift is
reported. Feedforward: the set point is predicted ``delay_s`` ahead.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role
from es_physics.effects.identifiable import Identifiable
from es_physics.effects.stages import Compensator, PlantContext, PlantStage


class DelayStage(PlantStage):
    """The command reaches the actuators ``steps`` internal steps late."""

    def __init__(self, steps: int) -> None:
        self.steps = steps

    def transport_steps(self) -> int:
        """Return the delay in internal steps."""
        return self.steps


class DelayPredictor(Compensator):
    """Predict the set point ``delay_s`` ahead from the slope of the last two set points."""

    def __init__(self, delay_s: float) -> None:
        self.delay_s = delay_s
        self._last: tuple[FloatArray, float] | None = None
        self._slope: FloatArray | None = None

    def retuned(self, delay_s: float) -> DelayPredictor:
        """Return a copy with a new delay and this one's state (this one is unchanged)."""
        other = DelayPredictor(delay_s)
        other._last, other._slope = self._last, self._slope
        return other

    def __call__(self, z: FloatArray, t: float) -> FloatArray:
        """Return the predicted set points [m] (never below 0 where ``z`` is not)."""
        if self.delay_s == 0.0:
            return z
        if self._last is not None and self._last[0].shape == z.shape:
            z_prev, t_prev = self._last
            if t > t_prev:
                self._slope = (z - z_prev) / (t - t_prev)
        else:
            self._slope = None
        self._last = (z, t)
        if self._slope is None:
            return z
        predicted = z + self.delay_s * self._slope
        # a straight-line prediction must not push a reachable set point below 0
        return np.asarray(np.where(z >= 0.0, np.maximum(predicted, 0.0), predicted), np.float64)

    def predict(self, z: FloatArray, t: float) -> FloatArray:
        """Return the set point predicted over the delay (see :meth:`__call__`)."""
        return self(z, t)


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
    identifiable: ClassVar[Mapping[str, Identifiable]] = {
        "delay_s": Identifiable.BEYOND_STAMP_JITTER
    }
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

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the delay resolved to the plant's internal step."""
        return DelayStage(round(settings["delay_s"] * context.substeps / context.dt))

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the set-point predictor, or None when ``delay_s`` is 0."""
        if values["delay_s"] == 0.0:
            return None
        if isinstance(previous, DelayPredictor):
            return previous.retuned(values["delay_s"])
        return DelayPredictor(values["delay_s"])
