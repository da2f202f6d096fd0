"""Self-sensing: fuse each actuator's own resonance reading with the model estimate.

A calibrated actuator i turns its resonance reading f_i [Hz] into a temperature

    T_i = T0 + (f_i - f0_i - a_V,i |V_i|) / a_T,i,

the voltage term corrected with the command in force (/dm/command). The thermal model
(:mod:`es_thermal.kalman`, corrected by the few NTCs) is right in its dynamics but wrong
between the sensors (offsets, unmeasured base plate, model error); the resonance readings
come round robin, a group per cycle. :class:`SelfSensingFusion` therefore estimates, per
actuator, the model's error c_i as a random walk with a scalar Kalman filter (vectorised over
the grid): every cycle its variance grows by ``drift**2 * dt``; a reading of actuator i
updates c_i with gain P_i / (P_i + R_i), R_i = (reading noise / a_T,i)**2; the output is
model + c. Between an actuator's readings the model carries the temperature's changes.

NaN means "not swept this cycle" and is no fault. A finite reading outside [``f_min_hz``,
``f_max_hz``], or whose temperature is more than ``gate_degc`` off the current fused estimate
(``acquire_gate_degc`` while the channel has no correction yet: the model alone may be
further off), is dropped as ``implausible`` (a failed channel, or a stuck one once the
temperature moves); a reading that repeats exactly while the model says the actuator's
temperature moved by more than ``stuck_band_degc`` since that value first came is ``stuck``
(a healthy channel's reading changes with every resolution step) and drops the channel's
correction; a channel without an accepted reading for ``stale_after`` seconds is
``stale`` and its correction falls back to zero (the model alone). All are counted in
:class:`ChannelHealth` for the node's diagnostics. Without any resonance data the output is
the model estimate unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Final

import numpy as np
import numpy.typing as npt

from es_common.arrays import BoolArray, FloatArray
from es_thermal.errors import CalibrationError, ThermalConfigError, ThermalInputError

#: Worst channels named in a health summary.
WORST_LISTED: Final = 5


@dataclass(frozen=True)
class ResonanceCalibration:
    """Per-actuator resonance law f = f0 + a_T (T - T0) + a_V |V|; arrays are flat (N,).

    Attributes:
        f0_hz: resonance at ``reference_temperature`` and 0 V [Hz].
        a_t_hz_per_degc: temperature sensitivity [Hz/degC] (non-zero).
        a_v_hz_per_v: sensitivity to |V| [Hz/V].
        reference_temperature: T0 [degC].
        f0_sd_hz: 1-sigma uncertainty of f0 [Hz] (0: exact).
        a_t_sd: 1-sigma uncertainty of a_T [Hz/degC].
        a_v_sd: 1-sigma uncertainty of a_V [Hz/V].

    """

    f0_hz: FloatArray
    a_t_hz_per_degc: FloatArray
    a_v_hz_per_v: FloatArray
    reference_temperature: float
    f0_sd_hz: FloatArray
    a_t_sd: FloatArray
    a_v_sd: FloatArray

    @classmethod
    def from_values(
        cls,
        count: int,
        *,
        f0_hz: npt.ArrayLike,
        a_t_hz_per_degc: npt.ArrayLike,
        a_v_hz_per_v: npt.ArrayLike,
        reference_temperature: float,
        f0_sd_hz: npt.ArrayLike = 0.0,
        a_t_sd: npt.ArrayLike = 0.0,
        a_v_sd: npt.ArrayLike = 0.0,
    ) -> ResonanceCalibration:
        """Build from values of length 1 (same for all) or ``count`` (row-major map).

        Raises:
            CalibrationError: wrong length, non-finite value or a zero a_T.

        """
        out = []
        for name, value in (
            ("f0_hz", f0_hz), ("a_t_hz_per_degc", a_t_hz_per_degc),
            ("a_v_hz_per_v", a_v_hz_per_v), ("f0_sd_hz", f0_sd_hz), ("a_t_sd", a_t_sd),
            ("a_v_sd", a_v_sd),
        ):  # fmt: skip
            arr = np.atleast_1d(np.asarray(value, float)).ravel()
            if arr.size not in (1, count):
                raise CalibrationError(
                    f"resonance.{name} has {arr.size} values, expected 1 or {count}"
                )
            if not np.all(np.isfinite(arr)):
                raise CalibrationError(f"resonance.{name} holds NaN or inf")
            out.append(np.broadcast_to(arr, (count,)).copy())
        if np.any(out[1] == 0.0):
            raise CalibrationError("resonance.a_t_hz_per_degc must be non-zero")
        if not np.isfinite(reference_temperature):
            raise CalibrationError("resonance.reference_temperature must be finite")
        f0, a_t, a_v, f0_sd, a_t_sd_, a_v_sd_ = out
        return cls(
            f0, a_t, a_v, float(reference_temperature), np.abs(f0_sd), np.abs(a_t_sd_),
            np.abs(a_v_sd_),
        )  # fmt: skip

    def temperature(self, frequency: FloatArray, voltage: FloatArray) -> FloatArray:
        """Return the temperature (N,) [degC] each reading (N,) [Hz] means at ``voltage`` [V]."""
        shifted = frequency - self.f0_hz - self.a_v_hz_per_v * np.abs(voltage)
        return self.reference_temperature + shifted / self.a_t_hz_per_degc

    def variance(self, noise_hz: float, temperature: FloatArray, voltage: FloatArray) -> FloatArray:
        """Return the variance (N,) [degC^2] of a temperature read at a temperature and voltage.

        Reading noise plus the calibration's uncertainties, propagated through the law (the
        a_T and a_V terms grow with the distance from T0 and with |V|).
        """
        spread = (
            noise_hz**2
            + self.f0_sd_hz**2
            + (self.a_t_sd * (temperature - self.reference_temperature)) ** 2
            + (self.a_v_sd * voltage) ** 2
        )
        return spread / self.a_t_hz_per_degc**2


@dataclass(frozen=True)
class FusionConfig:
    """How much the fusion trusts the readings and how it screens them.

    Attributes:
        noise_hz: rms noise of one reading [Hz] (sweep noise and resolution).
        drift: random-walk intensity of the model's error per actuator [degC/sqrt(s)].
        gate_degc: a reading this far off the fused estimate is implausible [degC].
        acquire_gate_degc: the same for a channel without a current correction (first
            reading, or after it went stale): the model alone may be further off [degC].
        stale_after: a channel without an accepted reading this long is stale [s].
        stuck_band_degc: a reading unchanged while the model moves this much is stuck [degC].
        f_min_hz, f_max_hz: plausible reading range [Hz].

    """

    noise_hz: float = 15.0
    drift: float = 0.01
    gate_degc: float = 1.0
    acquire_gate_degc: float = 5.0
    stale_after: float = 5.0
    stuck_band_degc: float = 0.3
    f_min_hz: float = 1.0e5
    f_max_hz: float = 1.0e7

    def __post_init__(self) -> None:
        """Check the values.

        Raises:
            ThermalConfigError: a value out of range (the message names it).

        """
        for name in (
            "noise_hz", "drift", "gate_degc", "acquire_gate_degc", "stale_after",
            "stuck_band_degc",
        ):  # fmt: skip
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0.0:
                raise ThermalConfigError(f"self-sensing {name}={value} must be finite and > 0")
        if not self.f_min_hz < self.f_max_hz:
            raise ThermalConfigError("self-sensing f_min_hz must be below f_max_hz")

    def time_scaled(self, time_scale: float) -> FusionConfig:
        """Return the configuration for a run whose slow times are multiplied by ``time_scale``.

        As for the Kalman filter's intensities, the drift grows by ``1/sqrt(time_scale)``.
        """
        return replace(self, drift=self.drift / float(np.sqrt(time_scale)))


@dataclass(frozen=True)
class ChannelHealth:
    """The verdict on one cycle's resonance readings (flat (N,) masks).

    Attributes:
        accepted: readings used this cycle.
        implausible: finite readings dropped (out of range or beyond the gate).
        stale: channels without an accepted reading for ``stale_after``.
        received: a resonance message came this cycle.
        stuck: readings dropped as stuck (repeating while the model moved).

    """

    accepted: BoolArray
    implausible: BoolArray
    stale: BoolArray
    received: bool
    stuck: BoolArray

    def counts(self) -> dict[str, int]:
        """Return the number of channels per verdict."""
        return {
            "resonance_accepted": int(np.count_nonzero(self.accepted)),
            "resonance_implausible": int(np.count_nonzero(self.implausible)),
            "resonance_stale": int(np.count_nonzero(self.stale)),
            "resonance_stuck": int(np.count_nonzero(self.stuck)),
        }

    def worst(self) -> dict[str, str]:
        """Return the first few implausible and stale channel indices (row-major)."""
        out = {}
        for name, mask in (
            ("implausible", self.implausible), ("stale", self.stale), ("stuck", self.stuck)
        ):  # fmt: skip
            index = np.flatnonzero(mask)[:WORST_LISTED]
            if index.size:
                out[f"resonance_first_{name}"] = ", ".join(str(i) for i in index)
        return out


class SelfSensingFusion:
    """Per-actuator correction of the model estimate from resonance readings.

    Args:
        calibration: the per-actuator resonance law (N actuators).
        config: noise, drift and screening.
        disabled: row-major indices of channels whose readings are never used (a channel
            the calibration could not fit).

    Raises:
        CalibrationError: a disabled index off the grid.

    """

    def __init__(
        self,
        calibration: ResonanceCalibration,
        config: FusionConfig,
        disabled: tuple[int, ...] = (),
    ) -> None:
        """Build the fusion of ``calibration`` with ``config``; ``disabled`` channels are dropped.

        Raises:
            CalibrationError: a disabled index off the grid.

        """
        self.calibration = calibration
        self.config = config
        n = calibration.f0_hz.size
        self.count = n
        if any(not 0 <= i < n for i in disabled):
            raise CalibrationError(f"resonance.disabled_channels must be within 0..{n - 1}")
        self._enabled = np.ones(n, bool)
        self._enabled[list(disabled)] = False
        self._voltage: FloatArray = np.zeros(n)
        self._correction: FloatArray = np.zeros(n)
        self._variance: FloatArray = np.full(n, np.inf)
        self._last_accepted: FloatArray = np.full(n, -np.inf)
        # the last distinct reading per channel and the model's estimate when it came
        self._held_reading: FloatArray = np.full(n, np.nan)
        self._held_model: FloatArray = np.full(n, np.nan)
        self._last_time: float | None = None
        self._first_time: float | None = None
        self.latest: ChannelHealth | None = None

    @property
    def correction(self) -> FloatArray:
        """The current per-actuator correction of the model (N,) [degC] (copy)."""
        return self._correction.copy()

    def set_command(self, voltage: npt.ArrayLike) -> None:
        """Take the command in force (N,) or (R, C) [V] for the voltage term.

        Raises:
            ThermalInputError: wrong size or a non-finite value (the previous command is kept).

        """
        volts = np.asarray(voltage, float).ravel()
        if volts.size != self.count:
            raise ThermalInputError(f"command has {volts.size} values, expected {self.count}")
        if not np.all(np.isfinite(volts)):
            raise ThermalInputError("command holds NaN or inf")
        self._voltage = volts

    def restart(self) -> None:
        """Forget every correction (after the model estimate restarted)."""
        self._correction[:] = 0.0
        self._variance[:] = np.inf
        self._last_accepted[:] = -np.inf
        self._held_reading[:] = np.nan
        self._held_model[:] = np.nan
        self._last_time = None
        self._first_time = None

    @property
    def voltage(self) -> FloatArray:
        """The command in force as last set (N,) [V] (copy)."""
        return self._voltage.copy()

    def fuse(
        self,
        now: float,
        model: FloatArray,
        frequency: FloatArray | None,
        voltage: FloatArray | None = None,
    ) -> FloatArray:
        """Correct the model estimate (N,) [degC] at ``now`` [s] with this cycle's readings.

        Args:
            now: sample time [s].
            model: the model estimate (N,) or (R, C) [degC].
            frequency: this cycle's readings (N,) or (R, C) [Hz], NaN where not swept, or
                None when no message came.
            voltage: the command in force during the sweep (N,) [V]; default: the last one
                set with :meth:`set_command`.

        Returns:
            The fused estimate, same shape as ``model``.

        Raises:
            ThermalInputError: ``frequency`` or ``model`` of the wrong size (nothing is updated).

        """
        estimate = np.asarray(model, float)
        flat = estimate.ravel()
        if flat.size != self.count:
            raise ThermalInputError(f"model estimate has {flat.size} values, expected {self.count}")
        readings = None if frequency is None else np.asarray(frequency, float).ravel()
        if readings is not None and readings.size != self.count:
            raise ThermalInputError(f"resonance has {readings.size} values, expected {self.count}")
        if readings is not None:
            readings = np.where(self._enabled, readings, np.nan)
        cfg = self.config
        volts = self._voltage if voltage is None else np.asarray(voltage, float).ravel()
        if self._last_time is not None and now > self._last_time:
            self._variance += cfg.drift**2 * (now - self._last_time)
        self._last_time = now
        accepted = np.zeros(self.count, bool)
        implausible = np.zeros(self.count, bool)
        stuck = np.zeros(self.count, bool)
        if readings is not None:
            finite = np.isfinite(readings)
            in_range = finite & (readings >= cfg.f_min_hz) & (readings <= cfg.f_max_hz)
            changed = in_range & (readings != self._held_reading)
            self._held_reading = np.where(changed, readings, self._held_reading)
            self._held_model = np.where(changed, flat, self._held_model)
            moved = np.abs(flat - self._held_model) > cfg.stuck_band_degc
            stuck = in_range & ~changed & moved
            self._correction[stuck] = 0.0
            self._variance[stuck] = np.inf
            in_range &= ~stuck
            sensed = self.calibration.temperature(np.where(in_range, readings, 0.0), volts)
            innovation = np.where(in_range, sensed - flat - self._correction, 0.0)
            known = np.isfinite(self._variance)
            gate = np.where(known, cfg.gate_degc, cfg.acquire_gate_degc)
            accepted = in_range & (np.abs(innovation) <= gate)
            implausible = finite & ~accepted & ~stuck
            noise = self.calibration.variance(cfg.noise_hz, sensed, volts)
            prior = np.where(known, self._variance, 0.0)
            gain = np.where(known, prior / (prior + noise), 1.0)
            self._correction += np.where(accepted, gain * innovation, 0.0)
            updated = np.where(known, (1.0 - gain) * prior, noise)
            self._variance = np.where(accepted, updated, self._variance)
            self._last_accepted[accepted] = now
        if self._first_time is None:
            self._first_time = now
        stale = self._enabled & (
            now - np.maximum(self._last_accepted, self._first_time) > cfg.stale_after
        )
        self._correction[stale] = 0.0
        self._variance[stale] = np.inf
        self.latest = ChannelHealth(accepted, implausible, stale, readings is not None, stuck)
        return (flat + self._correction).reshape(estimate.shape)
