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
:class:`HeatingEstimate`).

Calibration (role ``HEATING``): T_a = T_s + g LP_tau(P_drive), P_drive the same measure
(:func:`loss_measure`, :meth:`SelfHeating.drive_signal`) with the running mean over a window
W; unknowns g, log tau and log W, reported as ``gain`` [degC s/V^2], ``tau_s`` [s] and
``mean_window_s`` [s] (and W set in the compensation). W is fitted because the plant's
split of the drive into its level and its swing is its own (a different window leaves a
residual heating error of the size of the noise); it is held within ``MEAN_WINDOW_RANGE_S``
(beyond it the measure no longer changes with W). For a sine of amplitude A at f the steady
excess is g f A^2 (the mean of P_drive).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import ClassVar, Final

import numpy as np
from scipy.signal import lfilter

from es_physics.effects.base import (
    Effect,
    FittedEffect,
    FloatArray,
    Parameter,
    Role,
    filter_undetermined,
)
from es_physics.effects.identifiable import Identifiable
from es_physics.effects.stages import Compensator, Drive, PlantContext, PlantStage
from es_physics.errors import EffectParameterError

#: Running-mean window the calibration's drive measure starts from [s].
MEAN_WINDOW_S: Final = 1.0
#: Running-mean windows the calibration's drive measure can take [s].
MEAN_WINDOW_RANGE_S: Final = (0.05, 50.0)
#: Starting thermal gain of the calibration's fit [degC s/V^2] (tens of mdegC at 100 V, 1 Hz).
START_GAIN: Final = 1e-5
#: Time constants the calibration starts from [s].
START_TAUS_S: Final = (0.5, 3.0)
#: Time constants the calibration accepts [s].
TAU_RANGE_S: Final = (1e-3, 1e4)


def loss_measure(
    previous: FloatArray, drive: FloatArray, mean: FloatArray, dt: float
) -> FloatArray:
    """Return P_drive = |V_k - V_(k-1)| |(V_k + V_(k-1)) / 2 - V_mean| / (2 dt) [V^2/s].

    The loss of the switch from ``previous`` to ``drive`` [V] spread over the interval ``dt``
    [s] (> 0), ``mean`` the running mean of the drive before the switch [V].
    """
    swing = np.abs(drive - previous)
    level = np.abs(0.5 * (drive + previous) - mean)
    return np.asarray(0.5 * swing * level / dt, np.float64)


class HeatingStage(PlantStage):
    """The actuators' dielectric loss from the switch of the applied drive in each step."""

    def __init__(self, loss: float, mean_window_s: float, context: PlantContext) -> None:
        self.loss = loss
        self.dt = context.dt
        self._mean_decay = float(np.exp(-context.dt / mean_window_s))
        self._mean_voltage = np.zeros(context.shape)

    def heating(self, drive: Drive) -> FloatArray | None:
        """Return p_d |dV| |V_mid - V_mean| / (2 dt) [W] and advance the running mean."""
        previous, current = drive.previous, drive.current
        swing = np.abs(current - previous)
        level = np.abs(0.5 * (current + previous) - self._mean_voltage)
        power = np.asarray(0.5 * self.loss * swing * level / self.dt, np.float64)
        self._mean_voltage = current + (self._mean_voltage - current) * self._mean_decay
        return power


class HeatingEstimate(Compensator):
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
        power = loss_measure(previous, drive, mean, dt)
        mean = drive + (mean - drive) * float(np.exp(-dt / self.mean_window_s))
        self._state = (excess, power, drive, t, mean)
        self._interval = dt


    def law_temperature(self, T: FloatArray, t: float) -> FloatArray:
        """Return T + dT: the law at the actuator's own temperature [degC]."""
        return np.asarray(T + self.at(t), np.float64)

    def commit(self, sent: FloatArray, drive: FloatArray, t: float) -> FloatArray:
        """Take the command ``sent`` (its loss heats the actuator); pass ``drive`` on."""
        self.apply(sent, t)
        return drive


class SelfHeating(Effect):
    """Dielectric-loss heating of the actuators."""

    name: ClassVar[str] = "self_heating"
    summary: ClassVar[str] = "dielectric loss heats the actuator with V^2 and drive frequency"
    role: ClassVar[Role] = Role.HEATING
    simulated: ClassVar[bool] = True
    fit_parameters: ClassVar[tuple[str, ...]] = ("gain", "log_tau_s", "log_mean_window_s")
    signal_parameters: ClassVar[tuple[str, ...]] = ("log_mean_window_s",)
    local_options: ClassVar[tuple[str, ...]] = ("gain",)
    plant: ClassVar[tuple[Parameter, ...]] = (
        Parameter("loss_w_per_hz_v2", "W/(Hz V^2)", 0.0, 1e-3, 4.7e-9, "loss coefficient p_d"),
        Parameter("mean_window_s", "s", 0.0, 1e6, 1.0, "running-mean window", low_open=True),
    )
    identifiable: ClassVar[Mapping[str, Identifiable]] = {"tau_s": Identifiable.TIME_CONSTANT}
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "self_heating_gain", "degC s/V^2", 0.0, 1.0, 0.0, "excess degC per V^2/s (0 = off)"
        ),
        Parameter("self_heating_tau_s", "s", 1e-6, 1e6, 1.0, "time constant of the excess"),
        Parameter(
            "self_heating_mean_window_s", "s", 1e-6, 1e6, MEAN_WINDOW_S, "running mean of the drive"
        ),
    )

    def starts(self, duration_s: float) -> list[dict[str, float]]:
        """Start from a typical gain (so tau has a gradient) at a short and a long tau."""
        return [
            {
                "gain": START_GAIN,
                "log_tau_s": math.log(tau),
                "log_mean_window_s": math.log(MEAN_WINDOW_S),
            }
            for tau in START_TAUS_S
        ]

    @staticmethod
    def mean_window(shape: Sequence[float]) -> tuple[float, bool]:
        """Return the window W [s] of ``shape`` (log W; empty: ``MEAN_WINDOW_S``), in range.

        The flag says whether W lies inside ``MEAN_WINDOW_RANGE_S`` (outside, it is held at
        the bound and the measure does not change with log W).
        """
        if not shape:
            return MEAN_WINDOW_S, True
        low, high = (math.log(v) for v in MEAN_WINDOW_RANGE_S)
        log_window = float(shape[0])
        # decided on log W: exp(log(50)) rounds below 50, so a held bound looked inside
        return math.exp(min(max(log_window, low), high)), low < log_window < high

    @staticmethod
    def _means(command: FloatArray, keep: float) -> FloatArray:
        """Return the running mean before each command (N, A) [V].

        m_0 = V_0, m_(k+1) = V_k + (m_k - V_k) keep.
        """
        # y_k = keep y_(k-1) + (1 - keep) x_(k-1): the state starts at V_0, so y_0 = V_0
        means, _ = lfilter([0.0, 1.0 - keep], [1.0, -keep], command, axis=0, zi=command[:1])
        return np.asarray(means, np.float64)

    def drive_signal(
        self, command: FloatArray, period: float, shape: Sequence[float] = ()
    ) -> FloatArray:
        """Return P_drive (N, A) [V^2/s] of a uniformly sampled command (N, A) [V].

        Row k holds the loss of the switch to command k (row 0: none), the running mean of
        time constant W (``shape``: (log W,); empty: ``MEAN_WINDOW_S``) started at the first
        command.
        """
        command = np.asarray(command, np.float64)
        out = np.zeros_like(command)
        if command.shape[0] < 2:
            return out
        window, _ = self.mean_window(shape)
        means = self._means(command, math.exp(-period / window))
        out[1:] = loss_measure(command[:-1], command[1:], means[1:], period)
        return out

    def drive_signal_slopes(
        self, command: FloatArray, period: float, shape: Sequence[float]
    ) -> tuple[FloatArray, ...]:
        """Return (d P_drive / d log W,) (N, A) [V^2/s] (0 with W held at a bound)."""
        command = np.asarray(command, np.float64)
        out = np.zeros_like(command)
        window, inside = self.mean_window(shape)
        if command.shape[0] < 2 or not inside:
            return (out,)
        keep = math.exp(-period / window)
        means = self._means(command, keep)
        # s_k = d m_k / d log W: s_0 = 0, s_(k+1) = keep s_k + (m_k - V_k) keep period / W
        drive = (means - command) * (keep * period / window)
        slope, _ = lfilter([0.0, 1.0], [1.0, -keep], drive, axis=0, zi=np.zeros_like(command[:1]))
        swing = np.abs(command[1:] - command[:-1])
        level = 0.5 * (command[1:] + command[:-1]) - means[1:]
        out[1:] = -0.5 * swing * np.sign(level) * slope[1:] / period
        return (out,)

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return ``gain`` [degC s/V^2], ``tau_s`` [s] and ``mean_window_s`` [s]."""
        return {
            "gain": float(fit.values["gain"]),
            "tau_s": float(np.exp(fit.values["log_tau_s"])),
            "mean_window_s": self.mean_window((fit.values["log_mean_window_s"],))[0],
        }

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Propagate the log-parameters' uncertainties to ``tau_s`` and ``mean_window_s``."""
        return {
            "gain": float(fit.sigma["gain"]),
            "tau_s": float(np.exp(fit.values["log_tau_s"])) * float(fit.sigma["log_tau_s"]),
            "mean_window_s": self.mean_window((fit.values["log_mean_window_s"],))[0]
            * float(fit.sigma["log_mean_window_s"]),
        }

    def problem(self, reported: dict[str, float]) -> str | None:
        """Reject a gain <= 0 (the drive cannot cool) or a tau outside ``TAU_RANGE_S``."""
        if not reported["gain"] > 0.0:
            return f"gain {reported['gain']:.3g} degC s/V^2 is not positive"
        low, high = TAU_RANGE_S
        if not low <= reported["tau_s"] <= high:
            return f"tau_s {reported['tau_s']:.3g} s outside [{low:g}, {high:g}]"
        return None

    def undetermined(self, fit: FittedEffect) -> str | None:
        """Reject a tau known to worse than a factor e, or a gain to worse than 100 %."""
        return filter_undetermined(fit, "gain", "log_tau_s")

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Estimate the excess from the drive sent, with the fitted mean window."""
        return {
            "self_heating_gain": reported["gain"],
            "self_heating_tau_s": reported["tau_s"],
            "self_heating_mean_window_s": reported["mean_window_s"],
        }

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the dielectric loss of the drive."""
        return HeatingStage(settings["loss_w_per_hz_v2"], settings["mean_window_s"], context)

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the excess-temperature estimate, or None when the gain is 0.

        Raises:
            ValueError: as :class:`HeatingEstimate`.

        """
        gain = values["self_heating_gain"]
        if gain == 0.0:
            return None
        args = (gain, values["self_heating_tau_s"], values["self_heating_mean_window_s"])
        if isinstance(previous, HeatingEstimate):
            return previous.retuned(*args)
        return HeatingEstimate(*args)
