"""Self-heating by dielectric loss: the actuator runs warmer than its sensor under drive.

Plant only: P = p_d f V_amp^2 for a sine of frequency f; for any drive the plant uses the
equivalent p_d |V - V_mean| |dV/dt| / 2 (V_mean a running mean over ``mean_window_s``),
whose average over a sine period is exactly p_d f V_amp^2. Default p_d = pi C tan(delta) with
C = 0.05 uF and tan(delta) = 0.03: 4.7e-9 W/(Hz V^2), about 47 mW per actuator at 100 V
amplitude and 1 kHz, negligible at 1 Hz. No calibration model or compensation yet.
"""

from __future__ import annotations

from typing import ClassVar

from es_physics.effects.base import Effect, FittedEffect, Parameter, Role


class SelfHeating(Effect):
    """Dielectric-loss heating of the actuators."""

    name: ClassVar[str] = "self_heating"
    summary: ClassVar[str] = "dielectric loss heats the actuator with V^2 and drive frequency"
    role: ClassVar[Role] = Role.PLANT_ONLY
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = (
        Parameter("loss_w_per_hz_v2", "W/(Hz V^2)", 0.0, 1e-3, 4.7e-9, "loss coefficient p_d"),
        Parameter("mean_window_s", "s", 0.0, 1e6, 1.0, "running-mean window", low_open=True),
    )

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return the values as given (the effect is not fitted)."""
        return {k: float(v) for k, v in fit.values.items()}
