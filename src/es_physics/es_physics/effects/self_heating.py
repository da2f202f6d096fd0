"""Self-heating by dielectric loss: the actuator runs warmer than its sensor under drive.

Plant: P = p_d f V_amp^2 for a sine of frequency f; for any drive the plant uses the
equivalent p_d |V - V_mean| |dV/dt| / 2 (V_mean a running mean over ``mean_window_s``),
whose average over a sine period is exactly p_d f V_amp^2. Default p_d = pi C tan(delta) with
C = 0.05 uF and tan(delta) = 0.03: 4.7e-9 W/(Hz V^2), about 47 mW per actuator at 100 V
amplitude and 1 kHz, negligible at 1 Hz.

Feedforward: the actuator's excess temperature over the measured one follows, from the
drive's own history, d(dT)/dt = (g P_drive - dT) / tau with P_drive = |V - V_mean| |dV/dt| / 2
[V^2/s] (the plant's measure without p_d, which g absorbs) and the law evaluated at T + dT
(``compensation.self_heating_gain``, ``compensation.self_heating_tau_s``,
:class:`HeatingEstimate`). No calibration model yet.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role
from es_physics.errors import EffectParameterError


class HeatingEstimate:
    """Excess temperature dT [degC] of each actuator from its drive history (see above).

    The drive is held between commands. A command V_k sent at t_k dissipates, until the next
    one, the power measure |V_k - V_(k-1)| |(V_k + V_(k-1)) / 2 - V_mean| / (2 dt) with dt
    the last command interval (the coming one is not known yet) and V_mean a running mean of
    time constant ``mean_window_s``; dT relaxes towards g times it over that interval (exact
    for a held power) and towards 0 after it while no new drive comes.
    """

    def __init__(self, gain: float, tau_s: float, mean_window_s: float) -> None:
        """Set g [degC s/V^2], tau [s] (> 0) and the running-mean window [s] (> 0).

        Raises:
            EffectParameterError: tau or the window not positive, or g negative (or not finite).

        """
        if not (np.isfinite(gain) and gain >= 0.0):
            raise EffectParameterError(f"self-heating gain {gain!r} must be >= 0")
        for what, value in (("tau", tau_s), ("mean window", mean_window_s)):
            if not (np.isfinite(value) and value > 0.0):
                raise EffectParameterError(f"self-heating {what} {value!r} s must be > 0")
        self.gain = gain
        self.tau_s = tau_s
        self.mean_window_s = mean_window_s
        #: dT [degC] when the last drive was sent, the power measure since [V^2/s], the drive
        #: [V] and its time [s], and the running mean [V]; None before the first drive.
        self._state: tuple[FloatArray, FloatArray, FloatArray, float, FloatArray] | None = None
        #: the last command interval [s], over which the last switch's loss is spread
        self._interval = 0.0

    @property
    def active(self) -> bool:
        """Whether the estimate can be non-zero (g > 0)."""
        return self.gain > 0.0

    def retuned(self, gain: float, tau_s: float, mean_window_s: float) -> HeatingEstimate:
        """Return a copy with new parameters and this one's state (this one is unchanged).

        Raises:
            EffectParameterError: as the constructor.

        """
        other = HeatingEstimate(gain, tau_s, mean_window_s)
        other._state, other._interval = self._state, self._interval
        return other

    def at(self, t: float) -> FloatArray | float:
        """Return dT [degC] at time ``t`` [s] (0 before the first drive)."""
        if self._state is None:
            return 0.0
        excess, power, _, sent, _ = self._state
        elapsed = max(t - sent, 0.0)
        heated = min(elapsed, self._interval)  # the switch's loss lasts one command interval
        target = self.gain * power
        warm = target + (excess - target) * float(np.exp(-heated / self.tau_s))
        return np.asarray(warm * float(np.exp(-(elapsed - heated) / self.tau_s)), np.float64)

    def apply(self, drive: FloatArray, t: float) -> None:
        """Take the drive [V] sent at ``t`` [s] (call in time order)."""
        drive = np.array(drive, np.float64)
        if self._state is None:
            zero = np.zeros_like(drive)
            self._state = (zero, zero, drive, t, drive.copy())
            return
        _, _, previous, sent, mean = self._state
        dt = t - sent
        if dt <= 0.0:
            return
        excess = np.asarray(self.at(t), np.float64)
        swing = np.abs(drive - previous)
        level = np.abs(0.5 * (drive + previous) - mean)
        power = 0.5 * swing * level / dt
        mean = drive + (mean - drive) * float(np.exp(-dt / self.mean_window_s))
        self._state = (excess, power, drive, t, mean)
        self._interval = dt


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
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "self_heating_gain", "degC s/V^2", 0.0, 1.0, 0.0, "excess degC per V^2/s (0 = off)"
        ),
        Parameter("self_heating_tau_s", "s", 1e-6, 1e6, 1.0, "time constant of the excess"),
        Parameter(
            "self_heating_mean_window_s", "s", 1e-6, 1e6, 1.0, "running mean of the drive"
        ),
    )

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return the values as given (the effect is not fitted)."""
        return {k: float(v) for k, v in fit.values.items()}
