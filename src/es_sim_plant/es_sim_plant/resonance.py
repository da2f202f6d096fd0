"""Self-sensing: the simulated measurement of every actuator's thickness-mode resonance.

The thesis (chapter 3, table 3-2) measured the thickness-mode resonance of a PMN-PT actuator
near 1 MHz moving +3227 Hz/degC with temperature but only -80 Hz/V with DC bias, so a small
high-frequency sweep on top of the drive reads each actuator's own temperature. The
simulated reading of actuator i is

    f_i = f0_i + a_T,i (T_i - T0) + a_V,i |V_i| + noise, quantised to the frequency step,

with a seeded manufacturing spread of f0 (absolute, Hz) and of a_T and a_V (relative).

Sweep model (documented here, used for noise and resolution): a sweep steps the drive's
small-signal frequency in ``frequency_step_hz`` steps across ``span_hz`` around the tracked
resonance and dwells ``dwell_s`` at each point, so one sweep takes
``sweep_time = (span_hz / frequency_step_hz + 1) * dwell_s``. The resonance is the sweep
point of lowest impedance: the reading is quantised to ``frequency_step_hz`` (the
resolution), and white measurement noise of rms ``noise_density / sqrt(sweep_time)`` [Hz]
(``noise_density`` in Hz sqrt(s): a longer sweep averages more) comes on top.

Round robin: a multiplexer connects ``group_size`` actuators at a time to the sweep
channels, one group per temperature sample; actuator i (row-major) is in group
``i % groups`` (``groups = ceil(N / group_size)``), so every group spreads over the whole
grid. Actuators not swept in a cycle read NaN.

Failures (``failed_channels``, row-major indices): ``nan`` (never a reading), ``stuck``
(repeats its first reading) or ``implausible`` (reads ``implausible_offset_hz`` away).

Everything is pure numpy; the plant draws the spread and the noise from their own seed
streams, so switching the measurement on leaves every other random draw unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from es_common.arrays import FloatArray
from es_sim_plant.errors import ScenarioError

#: The thesis's thickness-mode sensitivities (table 3-2, 100 V DC bias).
THESIS_A_T_HZ_PER_DEGC: Final = 3227.0
THESIS_A_V_HZ_PER_V: Final = -80.0
FAILURE_MODES: Final = ("nan", "stuck", "implausible")


@dataclass(frozen=True)
class ResonanceConfig:
    """The resonance measurement of a scenario (``resonance:`` mapping; off by default).

    Attributes:
        enabled: publish /dm/resonance.
        f0_hz: nominal resonance at ``reference_temperature`` and 0 V [Hz].
        f0_spread_hz: standard deviation of f0 over the actuators [Hz].
        a_t_hz_per_degc: nominal temperature sensitivity [Hz/degC].
        a_t_spread: relative standard deviation of a_T.
        a_v_hz_per_v: nominal sensitivity to |V| [Hz/V].
        a_v_spread: relative standard deviation of a_V.
        reference_temperature: T0 [degC].
        frequency_step_hz: sweep step = resolution of a reading [Hz].
        span_hz: sweep span [Hz].
        dwell_s: time per sweep point [s] (physical; not time-scaled).
        noise_density: reading noise times sqrt(sweep time) [Hz sqrt(s)].
        group_size: actuators swept at once (multiplexer channels).
        failed_channels: row-major indices of failed channels.
        failure: failure mode of those channels, one of :data:`FAILURE_MODES`.
        implausible_offset_hz: what an ``implausible`` channel reads off the truth [Hz].

    """

    enabled: bool = False
    f0_hz: float = 1.0e6
    f0_spread_hz: float = 5.0e3
    a_t_hz_per_degc: float = THESIS_A_T_HZ_PER_DEGC
    a_t_spread: float = 0.03
    a_v_hz_per_v: float = THESIS_A_V_HZ_PER_V
    a_v_spread: float = 0.1
    reference_temperature: float = 40.0
    frequency_step_hz: float = 20.0
    span_hz: float = 4000.0
    dwell_s: float = 1.0e-5
    noise_density: float = 0.5
    group_size: int = 48
    failed_channels: tuple[int, ...] = ()
    failure: str = "nan"
    implausible_offset_hz: float = 2.0e5

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> ResonanceConfig:
        """Build from a scenario's ``resonance`` mapping.

        Raises:
            ScenarioError: unknown keys, wrong types or out-of-range values.

        """
        values = dict(data or {})
        known = set(cls.__dataclass_fields__)
        unknown = set(values) - known
        if unknown:
            raise ScenarioError(
                f"resonance: unknown key(s) {sorted(unknown)}; known {sorted(known)}"
            )
        try:
            kwargs: dict[str, Any] = {}
            for name, value in values.items():
                if name == "enabled":
                    kwargs[name] = bool(value)
                elif name == "failure":
                    kwargs[name] = str(value)
                elif name == "group_size":
                    kwargs[name] = int(value)
                elif name == "failed_channels":
                    kwargs[name] = tuple(int(v) for v in value)
                else:
                    kwargs[name] = float(value)
            config = cls(**kwargs)
        except (TypeError, ValueError):
            raise ScenarioError(
                "resonance: values must be numbers (failed_channels a list)"
            ) from None
        config.validate()
        return config

    @property
    def sweep_time(self) -> float:
        """Duration of one sweep [s]."""
        return (self.span_hz / self.frequency_step_hz + 1.0) * self.dwell_s

    @property
    def noise_hz(self) -> float:
        """Rms white noise of one reading [Hz] (before quantisation)."""
        return self.noise_density / float(np.sqrt(self.sweep_time))

    def validate(self) -> None:
        """Raise ``ScenarioError`` with a readable reason when a value is out of range."""
        positive = ("f0_hz", "frequency_step_hz", "span_hz", "dwell_s")
        for name in positive:
            if not getattr(self, name) > 0.0:
                raise ScenarioError(f"resonance: {name} must be > 0")
        for name in ("f0_spread_hz", "a_t_spread", "a_v_spread", "noise_density"):
            if not getattr(self, name) >= 0.0:
                raise ScenarioError(f"resonance: {name} must be >= 0")
        if self.a_t_hz_per_degc == 0.0 or not np.isfinite(self.a_t_hz_per_degc):
            raise ScenarioError("resonance: a_t_hz_per_degc must be finite and non-zero")
        if self.group_size < 1:
            raise ScenarioError("resonance: group_size must be >= 1")
        if self.failure not in FAILURE_MODES:
            raise ScenarioError(f"resonance: failure must be one of {list(FAILURE_MODES)}")
        if any(i < 0 for i in self.failed_channels):
            raise ScenarioError("resonance: failed_channels must be >= 0")


class ResonanceSensor:
    """The resonance sweeps of one mirror: per-actuator truth, round robin, noise, failures.

    Args:
        shape: actuator grid (R, C).
        config: the measurement (see :class:`ResonanceConfig`).
        rng_spread: generator of the manufacturing spread (drawn once here).
        rng_noise: generator of the reading noise.

    Raises:
        ScenarioError: a failed channel is off the grid.

    """

    def __init__(
        self,
        shape: tuple[int, int],
        config: ResonanceConfig,
        rng_spread: np.random.Generator,
        rng_noise: np.random.Generator,
    ) -> None:
        """Build the sweeps for the grid from ``config`` and the two random streams.

        Raises:
            ScenarioError: bad keys, types or values (the message says which).

        """
        config.validate()
        self.shape = shape
        self.config = config
        n = shape[0] * shape[1]
        if any(i >= n for i in config.failed_channels):
            raise ScenarioError(f"resonance: failed_channels beyond the {n} actuators")
        draws = rng_spread.standard_normal((3, *shape))
        #: Per-actuator truth (R, C): f0 [Hz], a_T [Hz/degC], a_V [Hz/V].
        self.f0: FloatArray = config.f0_hz + config.f0_spread_hz * draws[0]
        self.a_t: FloatArray = config.a_t_hz_per_degc * (1.0 + config.a_t_spread * draws[1])
        self.a_v: FloatArray = config.a_v_hz_per_v * (1.0 + config.a_v_spread * draws[2])
        self.groups = -(-n // config.group_size)
        self._group_of = (np.arange(n) % self.groups).reshape(shape)
        self._failed = np.zeros(shape, bool)
        self._failed.flat[list(config.failed_channels)] = True
        self._stuck: FloatArray = np.full(shape, np.nan)
        self._rng = rng_noise
        self.cycle = 0

    def true_frequency(self, temperature: FloatArray, voltage: FloatArray) -> FloatArray:
        """Return the noise-free resonance (R, C) [Hz] at a temperature [degC] and a voltage [V]."""
        t0 = self.config.reference_temperature
        return self.f0 + self.a_t * (temperature - t0) + self.a_v * np.abs(voltage)

    def measure(self, temperature: FloatArray, voltage: FloatArray) -> FloatArray:
        """Sweep the next group; return the readings (R, C) [Hz], NaN where not swept.

        Draws noise for the whole grid every cycle (a fixed draw count per cycle keeps the
        stream reproducible whatever the group).
        """
        cfg = self.config
        swept = self._group_of == self.cycle % self.groups
        self.cycle += 1
        noise = cfg.noise_hz * self._rng.standard_normal(self.shape)
        step = cfg.frequency_step_hz
        reading = np.round((self.true_frequency(temperature, voltage) + noise) / step) * step
        if cfg.failure == "stuck":
            first = swept & self._failed & np.isnan(self._stuck)
            self._stuck[first] = reading[first]
            reading = np.where(self._failed, self._stuck, reading)
        elif cfg.failure == "implausible":
            reading = np.where(self._failed, reading + cfg.implausible_offset_hz, reading)
        else:
            reading = np.where(self._failed, np.nan, reading)
        return np.where(swept, reading, np.nan)
