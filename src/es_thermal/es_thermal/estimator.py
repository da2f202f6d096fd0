"""Per-actuator temperature estimate from sensor readings: the pure core of the thermal node.

:class:`TemperatureEstimator` checks every message's readings (:mod:`es_thermal.faults`),
feeds the valid ones to the selected estimator and returns an actuator-grid estimate, or no
estimate when no sensor is valid. Estimators:

- ``lowpass``: the thesis's scheme, a Butterworth low-pass per sensor
  (:mod:`es_thermal.lowpass`) then spatial interpolation to the actuators;
- ``model`` (default): a steady-state Kalman filter on the thermal network driven by the
  heat load (:mod:`es_thermal.kalman`).

A heat-load grid that is not credible (:func:`es_thermal.faults.heat_load_problem`: NaN/inf,
negative, above ``faults.max_heat_load`` per cell) is rejected with a ThermalInputError (a
ValueError) and the last accepted heat load is held, as if the message had not come: one
corrupt message must not drive the model's state away from the readings.

Time is given by the caller in seconds. The filters are discretised for a fixed sample
period; a gap of several periods between messages advances them that many periods.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np
from scipy import sparse

from es_common.arrays import BoolArray, FloatArray
from es_thermal.errors import ThermalConfigError, ThermalInputError
from es_thermal.faults import FaultConfig, SensorFaultMonitor, SensorHealth, heat_load_problem
from es_thermal.interpolation import interpolation_matrix
from es_thermal.kalman import KalmanTuning, ModelEstimator
from es_thermal.lowpass import DEFAULT_CUTOFF_HZ, DEFAULT_ORDER, LowpassBank
from es_thermal.network import NetworkParams, per_sensor, sensor_lags

ESTIMATORS: Final = ("model", "lowpass")
#: A gap longer than this many sample periods restarts the estimate from the readings
#: instead of running the model blind for that long.
MAX_GAP_PERIODS: Final = 1000
#: Interpolation matrices kept for this many distinct sets of valid sensors.
_INTERPOLATION_CACHE_SIZE: Final = 8


@dataclass(frozen=True)
class EstimatorConfig:
    """Everything that fixes an estimator; validated on construction.

    Attributes:
        rows, cols: actuator grid.
        positions: sensor (row, col) positions, shape (S, 2).
        kind: ``"model"`` or ``"lowpass"``.
        sample_period: sensor sample period the filters are discretised for [s].
        lowpass_cutoff_hz, lowpass_order: the low-pass filter.
        sensor_tau: first-order lag of the sensors [s], one for all or one per sensor
            (model estimator).
        sensor_offsets: what each sensor reads above its site's temperature [degC], one for
            all or one per sensor (a calibration's); subtracted from the readings.
        sensor_offset_sd: the offsets' uncertainty, 1 sigma [degC], one for all or one per
            sensor: a constant error of the estimate no filter can remove (reported).
        network: the thermal network the model estimator assumes.
        tuning: noise levels the model estimator assumes.
        faults: sensor fault thresholds.

    """

    rows: int
    cols: int
    positions: FloatArray
    kind: str = "model"
    sample_period: float = 0.1
    lowpass_cutoff_hz: float = DEFAULT_CUTOFF_HZ
    lowpass_order: int = DEFAULT_ORDER
    sensor_tau: float | FloatArray = 0.0
    sensor_offsets: float | FloatArray = 0.0
    sensor_offset_sd: float | FloatArray = 0.0
    network: NetworkParams = field(default_factory=NetworkParams)
    tuning: KalmanTuning = field(default_factory=KalmanTuning)
    faults: FaultConfig = field(default_factory=FaultConfig)

    def __post_init__(self) -> None:
        """Check the values.

        Raises:
            ThermalConfigError: a value out of range (the message names it).

        """
        if self.rows < 1 or self.cols < 1:
            raise ThermalConfigError(f"grid must be at least 1 x 1, got {self.rows} x {self.cols}")
        if self.kind not in ESTIMATORS:
            raise ThermalConfigError(f"estimator {self.kind!r} is not one of {list(ESTIMATORS)}")
        pos = np.asarray(self.positions)
        if pos.ndim != 2 or pos.shape[1] != 2 or pos.shape[0] < 1:
            raise ThermalConfigError(f"positions must have shape (S >= 1, 2), got {pos.shape}")
        if not np.isfinite(self.sample_period) or self.sample_period <= 0.0:
            raise ThermalConfigError(f"sample_period must be > 0, got {self.sample_period}")
        count = pos.shape[0]
        sensor_lags(self.sensor_tau, count)
        per_sensor(self.sensor_offsets, count, "sensor offsets")
        if np.any(per_sensor(self.sensor_offset_sd, count, "sensor offset sd") < 0.0):
            raise ThermalConfigError("sensor offset sd must be >= 0")

    @property
    def sensor_count(self) -> int:
        """Number of sensors S."""
        return int(np.asarray(self.positions).shape[0])


@dataclass(frozen=True)
class Estimate:
    """The outcome of one message.

    Attributes:
        time: when the readings were taken [s].
        temperatures: the R x C actuator estimate [degC], or None when no sensor was valid.
        health: the verdict on the readings.

    """

    time: float
    temperatures: FloatArray | None
    health: SensorHealth


class TemperatureEstimator:
    """Turns successive sensor messages (and the heat load) into actuator estimates."""

    def __init__(self, config: EstimatorConfig) -> None:
        self.config = config
        cfg = config
        self.shape = (cfg.rows, cfg.cols)
        self.positions: FloatArray = np.asarray(cfg.positions, float)
        self.monitor = SensorFaultMonitor(cfg.sensor_count, cfg.faults)
        self._cells = cfg.rows * cfg.cols
        self._offsets = per_sensor(cfg.sensor_offsets, cfg.sensor_count, "sensor offsets")
        self._heat_now: FloatArray = np.zeros(self._cells)
        self._heat_then: FloatArray = np.zeros(self._cells)
        self._interp_cache: dict[bytes, sparse.csr_matrix] = {}
        self._previous_valid: BoolArray = np.zeros(cfg.sensor_count, bool)
        self._last_update: float | None = None
        self.latest: Estimate | None = None
        self._lowpass: LowpassBank | None = None
        self._model: ModelEstimator | None = None
        if cfg.kind == "lowpass":
            self._lowpass = LowpassBank(
                cfg.sensor_count, cfg.sample_period, cfg.lowpass_cutoff_hz, cfg.lowpass_order
            )
        else:
            self._model = ModelEstimator(
                cfg.rows,
                cfg.cols,
                self.positions,
                params=cfg.network,
                sensor_tau=cfg.sensor_tau,
                sample_period=cfg.sample_period,
                tuning=cfg.tuning,
            )

    @property
    def model(self) -> ModelEstimator | None:
        """The model estimator (None for ``lowpass``)."""
        return self._model

    def set_heat_load(self, heat_load: FloatArray) -> None:
        """Take the newest absorbed power per actuator cell [W], shape (R, C).

        A heat load is the load from its sample time on: the model holds it until the next
        sample (the heat load of a sample time comes before that time's readings).

        Raises:
            ThermalInputError: wrong shape, or a value that is not finite, negative beyond
                ``faults.heat_load_tolerance`` or above ``faults.max_heat_load``; the last
                accepted heat load is kept.

        """
        grid = np.asarray(heat_load, dtype=float)
        if grid.shape != self.shape:
            raise ThermalInputError(f"heat load has shape {grid.shape}, expected {self.shape}")
        problem = heat_load_problem(grid, self.config.faults)
        if problem is not None:
            raise ThermalInputError(problem)
        self._heat_now = grid.ravel().copy()

    def restart(self) -> None:
        """Start the estimate afresh from the next readings (after an update failed midway).

        The filter state, the model-error estimates and the low-pass histories are rebuilt
        from the next message; the heat load and the sensor fault tracking are kept.
        """
        self._last_update = None

    def update(self, now: float, readings: FloatArray) -> Estimate:
        """Check and use one message of sensor readings (S,) taken at ``now`` [s].

        Returns an :class:`Estimate`; its ``temperatures`` is None when no reading is valid.

        Raises:
            ThermalInputError: ``readings`` has the wrong shape (nothing is updated).

        """
        health = self.monitor.check(readings, now)
        values = np.asarray(readings, dtype=float) - self._offsets
        steps, restart = self._periods_since_last(now)
        valid = health.valid
        heat = self._heat_then  # the load published at the previous sample held since
        temperatures: FloatArray | None = None
        if self._model is not None:
            temperatures = self._update_model(values, valid, heat, steps, restart)
        elif self._lowpass is not None:
            temperatures = self._update_lowpass(values, valid, steps, restart)
        self._heat_then = self._heat_now
        self._previous_valid = valid
        self._last_update = now
        self.latest = Estimate(now, temperatures, health)
        return self.latest

    def _periods_since_last(self, now: float) -> tuple[int, bool]:
        """Return (sample periods to advance, restart?).

        Restart on the first message, after a long gap, or when time runs backwards (a
        simulation restarted).
        """
        if self._last_update is None:
            return 0, True
        elapsed = now - self._last_update
        if elapsed < 0.0:
            return 0, True
        periods = round(elapsed / self.config.sample_period)
        if periods > MAX_GAP_PERIODS:
            return 0, True
        # Two messages stamped alike (a clock update racing the data) still are two samples.
        return max(1, periods), False

    def _interpolation(self, valid: BoolArray) -> sparse.csr_matrix:
        key = np.packbits(valid).tobytes()
        matrix = self._interp_cache.get(key)
        if matrix is None:
            if len(self._interp_cache) >= _INTERPOLATION_CACHE_SIZE:
                self._interp_cache.pop(next(iter(self._interp_cache)))
            matrix = interpolation_matrix(self.config.rows, self.config.cols, self.positions, valid)
            self._interp_cache[key] = matrix
        return matrix

    def _update_lowpass(
        self, values: FloatArray, valid: BoolArray, steps: int, restart: bool
    ) -> FloatArray | None:
        bank = self._lowpass
        assert bank is not None
        # A sensor coming back (or everything, after a restart) starts afresh at its value.
        bank.reset_channels(np.ones_like(valid) if restart else valid & ~self._previous_valid)
        for _ in range(max(1, steps)):
            output = bank.step(values, valid)
        if not np.any(valid):
            return None
        weights = self._interpolation(valid)
        return np.asarray(weights[:, valid] @ output[valid]).reshape(self.shape)

    def _update_model(
        self, values: FloatArray, valid: BoolArray, heat: FloatArray, steps: int, restart: bool
    ) -> FloatArray | None:
        model = self._model
        assert model is not None
        if restart or not model.initialised:
            if not np.any(valid):
                return None
            field = self._interpolation(valid)[:, valid] @ values[valid]
            model.initialise(field, values, valid)
        else:
            model.predict(heat, steps)
            if not np.any(valid):
                return None  # the model runs on through the outage, nothing is published
            model.correct(values, valid)
        return model.actuator_temperatures().reshape(self.shape)


class SampleClock:
    """Sample times of a periodic stream whose arrival times jitter.

    Under sim time a message can be handled before the clock update that precedes it, so
    its arrival time may read a period early or late. Consecutive samples are therefore
    counted (one ``period`` each); the clock is followed again only after a real gap (more
    than ``resync_periods`` periods) or when it runs backwards (a simulation restarted).
    """

    def __init__(self, period: float, resync_periods: float = 2.5) -> None:
        """Stamp a stream of nominal ``period`` [s]; resync after ``resync_periods`` periods off.

        Raises:
            ThermalConfigError: a value out of range (the message names it).

        """
        if period <= 0.0:
            raise ThermalConfigError(f"sample period must be > 0, got {period}")
        self.period = period
        self.resync_periods = resync_periods
        self._last_arrival: float | None = None
        self._last_stamp = 0.0

    def stamp(self, arrival: float) -> float:
        """Return the sample time of a message arriving at ``arrival`` [s]."""
        previous = self._last_arrival
        self._last_arrival = arrival
        elapsed = None if previous is None else arrival - previous
        if elapsed is None or not -self.period <= elapsed <= self.resync_periods * self.period:
            self._last_stamp = arrival
        else:
            self._last_stamp += self.period
        return self._last_stamp
