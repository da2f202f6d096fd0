"""Input fault detection: which readings the estimators may use, which heat loads they accept.

A sensor is excluded while its reading is not finite, outside the physical range, or stuck
(it stayed inside a narrow band for too long: a live sensor always shows some noise). The
stream as a whole is stale when no message came for too long (:class:`StaleWatch`); then no
sensor is valid. A heat-load grid is rejected as a whole when any cell is not finite, negative
beyond a rounding tolerance or above a physical maximum (:func:`heat_load_problem`).
Everything is vectorised; time is passed in by the caller (seconds, any epoch), so the logic
runs the same on ROS time, sim time, wall time or in a test.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from es_common.arrays import BoolArray, FloatArray, IntArray
from es_thermal.errors import ThermalConfigError, ThermalInputError


@dataclass(frozen=True)
class FaultConfig:
    """Thresholds of the sensor checks.

    Attributes:
        valid_min, valid_max: physical range of a reading [degC].
        stuck_time: a sensor whose reading stays inside ``stuck_band`` this long is stuck [s].
        stuck_band: peak-to-peak change below which a reading counts as unchanged [degC].
            Set it below the sensor noise (a live sensor leaves the band within a few
            samples) and above its quantisation step only if the noise is below one step.
        stale_timeout: no message for this long makes every sensor stale [s].
        max_heat_load: largest credible absorbed power in one actuator cell [W]. The default
            (10 W) is far above any real load (the simulator's exposure puts 2 W on a whole
            12 x 12 mirror; 10 mW per cell already heats an actuator by ~3 degC), yet low
            enough that a few samples of it cannot wreck the model estimator's state.
        heat_load_tolerance: negative loads down to minus this are accepted as rounding of a
            computed power map [W].

    """

    valid_min: float = -20.0
    valid_max: float = 120.0
    stuck_time: float = 10.0
    stuck_band: float = 1e-9
    stale_timeout: float = 2.0
    max_heat_load: float = 10.0
    heat_load_tolerance: float = 1e-6

    def __post_init__(self) -> None:
        """Check the values.

        Raises:
            ThermalConfigError: a value out of range (the message names it).

        """
        if not self.valid_min < self.valid_max:
            raise ThermalConfigError(
                f"valid_min {self.valid_min} must be below valid_max {self.valid_max}"
            )
        if self.stuck_time <= 0.0 or self.stuck_band < 0.0 or self.stale_timeout <= 0.0:
            raise ThermalConfigError("stuck_time and stale_timeout must be > 0, stuck_band >= 0")
        if not (np.isfinite(self.max_heat_load) and self.max_heat_load > 0.0):
            raise ThermalConfigError(
                f"max_heat_load must be finite and > 0, got {self.max_heat_load}"
            )
        if not (np.isfinite(self.heat_load_tolerance) and self.heat_load_tolerance >= 0.0):
            raise ThermalConfigError(
                f"heat_load_tolerance must be finite and >= 0, got {self.heat_load_tolerance}"
            )


@dataclass(frozen=True)
class SensorHealth:
    """The verdict on one message's readings (all masks shape (S,))."""

    valid: BoolArray
    non_finite: BoolArray
    out_of_range: BoolArray
    stuck: BoolArray

    @property
    def valid_count(self) -> int:
        """Number of usable sensors."""
        return int(np.count_nonzero(self.valid))

    def counts(self) -> dict[str, int]:
        """Return the number of sensors per verdict, for a diagnostic."""
        return {
            "valid": self.valid_count,
            "non_finite": int(np.count_nonzero(self.non_finite)),
            "out_of_range": int(np.count_nonzero(self.out_of_range)),
            "stuck": int(np.count_nonzero(self.stuck)),
        }

    def excluded_indices(self, limit: int = 5) -> IntArray:
        """Return the first ``limit`` excluded sensor indices."""
        return np.flatnonzero(~self.valid)[:limit].astype(np.int64)


class SensorFaultMonitor:
    """Tracks ``count`` sensors across messages and classifies every new set of readings."""

    def __init__(self, count: int, config: FaultConfig) -> None:
        self.count = count
        self.config = config
        self._band_low: FloatArray = np.full(count, np.nan)
        self._band_high: FloatArray = np.full(count, np.nan)
        self._band_since: FloatArray = np.full(count, np.nan)

    def check(self, readings: FloatArray, now: float) -> SensorHealth:
        """Classify ``readings`` (S,) received at ``now`` [s] and update the stuck tracking.

        Raises:
            ThermalInputError: ``readings`` does not hold exactly ``count`` values.

        """
        values = np.asarray(readings, dtype=float)
        if values.shape != (self.count,):
            raise ThermalInputError(
                f"expected {self.count} sensor readings, got shape {values.shape}"
            )
        cfg = self.config
        finite = np.isfinite(values)
        with np.errstate(invalid="ignore"):  # NaN and inf readings compare and subtract
            in_range = finite & (values >= cfg.valid_min) & (values <= cfg.valid_max)
            # A reading leaving the band (or a sensor (re)appearing) restarts its band.
            low = np.fmin(self._band_low, values)
            high = np.fmax(self._band_high, values)
            restart = in_range & (np.isnan(self._band_since) | (high - low > cfg.stuck_band))
        self._band_low = np.where(restart, values, np.where(in_range, low, np.nan))
        self._band_high = np.where(restart, values, np.where(in_range, high, np.nan))
        self._band_since = np.where(restart, now, np.where(in_range, self._band_since, np.nan))
        stuck = in_range & (now - self._band_since >= cfg.stuck_time)
        return SensorHealth(
            valid=in_range & ~stuck,
            non_finite=~finite,
            out_of_range=finite & ~in_range,
            stuck=stuck,
        )


def heat_load_problem(heat_load: FloatArray, config: FaultConfig) -> str | None:
    """Return why a heat-load grid [W per cell] is not credible, or None when it is.

    The grid is judged as a whole: one impossible cell means the message is corrupt.
    """
    values = np.asarray(heat_load, dtype=float)
    finite = np.isfinite(values)
    if not np.all(finite):
        return f"heat load holds NaN or inf in {int(np.count_nonzero(~finite))} cell(s)"
    if values.size == 0:
        return None
    lowest, highest = float(np.min(values)), float(np.max(values))
    if lowest < -config.heat_load_tolerance:
        return f"heat load {lowest:.4g} W in a cell is negative"
    if highest > config.max_heat_load:
        return (
            f"heat load {highest:.4g} W in a cell is above max_heat_load "
            f"{config.max_heat_load:g} W"
        )
    return None


class StaleWatch:
    """Tells whether a message stream went quiet for longer than ``timeout`` seconds."""

    def __init__(self, timeout: float) -> None:
        """Start with nothing seen; ``timeout`` [s] is the longest quiet stretch.

        Raises:
            ThermalConfigError: a value out of range (the message names it).

        """
        if timeout <= 0.0:
            raise ThermalConfigError(f"stale timeout must be > 0, got {timeout}")
        self.timeout = timeout
        self._last: float | None = None

    @property
    def seen(self) -> bool:
        """True once a message arrived."""
        return self._last is not None

    def feed(self, now: float) -> None:
        """Note a message arriving at ``now``."""
        self._last = now

    def is_stale(self, now: float) -> bool:
        """Return True when no message came yet or the last is older than ``timeout``."""
        return self._last is None or now - self._last > self.timeout
