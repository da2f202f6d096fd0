"""Sensor lag: the temperature sensor sits beside the actuator and lags behind it.

Plant: the sensor reads T_s with dT_s/dt = (T_a - T_s) / tau. Calibration: the actuator
leads the sensor, T_a = T_s + tau dT_s/dt. Feedforward: the lag undone by a Kalman filter
(:class:`TemperatureLead`, ``compensation.temperature_lead_s``) whose model is that lag behind
an actuator temperature that moves at a slowly changing rate (it follows ramps without lag)
and that may jump (a jump is taken where a reading departs from the prediction by more than
JUMP_GATE standard deviations). A plain lead T_s + tau dT_s/dt differentiates the sensor's
noise: on a 0.02 degC sensor read every 0.2 tau it amplifies the noise about threefold, while
the filter, smoothing where nothing jumps, comes well below the lag-free reading's noise.
The gate is wide (4 sigma) because a jump taken on noise throws the smoothing away: at 3 sigma
(one reading in 370) the quiet stretches stayed at the sensor's own noise whatever the
smoothing time. A real step is seldom over in one sample (an actuator settles on its base
over a few sensor periods), so for FOLLOW_TIME lags after a jump the filter follows faster
(smoothing FOLLOW_FILTER of the lag) and takes a further jump at FOLLOW_GATE sigma. A
calibration sets the quiet smoothing time (``temperature_lead_filter_s``) to
LEAD_FILTER_FRACTION of the lag. The sensor's noise is estimated from the readings as they
come (their second differences, robustly), starting from ``temperature_noise_degc``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, Final

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role
from es_physics.effects.identifiable import Identifiable
from es_physics.effects.stages import Compensator, PlantContext, PlantStage

#: The filter's smoothing time where nothing jumps, as a multiple of the calibrated lag.
LEAD_FILTER_FRACTION: Final = 4.0
#: A reading further than this many standard deviations from the prediction is a jump.
JUMP_GATE: Final = 4.0
#: How long after a jump the filter follows faster, as a multiple of the lag.
FOLLOW_TIME: Final = 2.5
#: The gate [standard deviations] for a further jump within FOLLOW_TIME of the last.
FOLLOW_GATE: Final = 3.0
#: The smoothing time within FOLLOW_TIME of a jump, as a multiple of the lag (at most the
#: quiet one).
FOLLOW_FILTER: Final = 0.25
#: Standard deviation of the actuator temperature's jump assumed at a detected jump, in
#: sensor noise standard deviations.
JUMP_SIZE: Final = 15.0
#: Shortest smoothing time as a fraction of the lag (keeps the process noise finite).
MIN_FILTER_FRACTION: Final = 1e-3
#: Weight of a new reading in the running mean of the absolute second difference.
NOISE_WEIGHT: Final = 1.0 / 100.0
#: A second difference counts at most this many times the running mean (a jump does not
#: inflate the noise estimate).
NOISE_CLIP: Final = 2.5
#: Smallest noise estimate as a fraction of the first (a noise-free sensor keeps the filter
#: finite).
NOISE_FLOOR_FRACTION: Final = 1e-3
#: Mean absolute second difference of white noise of standard deviation 1:
#: sqrt(6) sqrt(2 / pi).
_MEAN_ABS_D2: Final = float(np.sqrt(6.0) * np.sqrt(2.0 / np.pi))


class SensorLagStage(PlantStage):
    """The sensor's first-order lag (the sensor array applies it)."""

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s

    def sensor_lag_s(self) -> float | None:
        """Return tau [s]."""
        return self.tau_s


class TemperatureLead(Compensator):
    """Kalman estimate of the actuator temperature behind a lagging sensor, per actuator.

    State per actuator: actuator temperature T_a [degC], its rate [degC/s] and the sensor's
    temperature T_s [degC]; T_s follows T_a with the first-order lag ``tau_s`` (exact
    discretisation for a T_a ramp over each sample interval), the rate changes by white
    noise of intensity noise^2 / filter^3 [degC^2/s^3], the sensor adds white noise. A
    reading whose innovation exceeds JUMP_GATE standard deviations adds a jump of JUMP_SIZE
    noise standard deviations to T_a's uncertainty before the update, so a step is followed
    within a sample or two while quiet stretches stay smoothed; for FOLLOW_TIME lags after a
    jump the smoothing time is FOLLOW_FILTER lags and the gate FOLLOW_GATE (an actuator's
    step is not over in one sample). The noise's standard
    deviation per actuator starts at ``noise_degc`` and follows the running mean of the
    readings' absolute second differences (each clipped at NOISE_CLIP times that mean).

    Args:
        tau_s: the lag to undo [s] (0 = pass the temperature through).
        filter_s: smoothing time of the filter [s] (longer: less noise, slower to follow a
            change of rate).
        noise_degc: first estimate of the sensor noise's standard deviation [degC], > 0.

    """

    def __init__(self, tau_s: float, filter_s: float, noise_degc: float) -> None:
        self.tau_s = tau_s
        self.filter_s = max(filter_s, MIN_FILTER_FRACTION * tau_s)
        self.noise_degc = noise_degc
        # per actuator, elementwise (no per-actuator 3 x 3 products): the state T_a, rate,
        # T_s and the covariance's six distinct entries 00, 01, 02, 11, 12, 22
        self._state: tuple[FloatArray, ...] | None = None
        self._cov: tuple[FloatArray, ...] = ()
        self._time = 0.0
        self._readings: list[FloatArray] = []  # the last two readings
        self._mean_abs_d2: FloatArray | None = None  # running mean of |second difference|
        self._since_jump: FloatArray | None = None  # time since the last jump [s]

    def retuned(self, tau_s: float, filter_s: float, noise_degc: float) -> TemperatureLead:
        """Return a copy with new parameters and this one's state (this one is unchanged)."""
        other = TemperatureLead(tau_s, filter_s, noise_degc)
        other._state, other._cov, other._time = self._state, self._cov, self._time
        other._readings, other._mean_abs_d2 = self._readings, self._mean_abs_d2
        other._since_jump = self._since_jump
        return other

    def _start(self, T: FloatArray, t: float) -> FloatArray:
        zero = np.zeros(T.shape)
        variance = np.full(T.shape, self.noise_degc**2)
        self._state = (np.array(T, np.float64), zero, np.array(T, np.float64))
        self._cov = (variance, zero, zero, variance / self.tau_s**2, zero, variance)
        self._time = t
        self._readings = [T]
        self._mean_abs_d2 = np.full(T.shape, self.noise_degc * _MEAN_ABS_D2)
        self._since_jump = np.full(T.shape, np.inf)
        return T

    def _noise_variance(self, T: FloatArray) -> FloatArray:
        """Update the noise estimate with reading ``T``; return its variance [degC^2]."""
        assert self._mean_abs_d2 is not None
        mean = self._mean_abs_d2
        if len(self._readings) == 2:
            d2 = np.abs(T - 2.0 * self._readings[1] + self._readings[0])
            mean = mean + NOISE_WEIGHT * (np.minimum(d2, NOISE_CLIP * mean) - mean)
            floor = NOISE_FLOOR_FRACTION * self.noise_degc * _MEAN_ABS_D2
            mean = self._mean_abs_d2 = np.maximum(mean, floor)
        self._readings = [*self._readings[-1:], T]
        return np.asarray((mean / _MEAN_ABS_D2) ** 2, np.float64)

    def __call__(self, T: FloatArray, t: float) -> FloatArray:
        """Return the actuator temperatures [degC] estimated from a sample ``T`` taken at ``t``.

        ``T`` holds finite sensor readings [degC] (any shape; a new shape restarts the
        filter at the readings). A sample not later than the last one changes nothing.
        """
        if self.tau_s == 0.0:
            return T
        if self._state is None or self._state[0].shape != T.shape:
            return self._start(T, t)
        a, v, s = self._state
        dt = t - self._time
        if dt <= 0.0:
            return np.array(a)
        self._time = t
        # transition F = [[1, dt, 0], [0, 1, 0], [g, h, e]]: T_s over a T_a ramp
        e = float(np.exp(-dt / self.tau_s))
        g = 1.0 - e
        h = dt - self.tau_s * g
        r = self._noise_variance(T)
        assert self._since_jump is not None
        self._since_jump = self._since_jump + dt
        following = self._since_jump <= FOLLOW_TIME * self.tau_s
        fast = min(FOLLOW_FILTER * self.tau_s, self.filter_s)
        smoothing = np.where(following, fast, self.filter_s)
        q = r / smoothing**3  # white noise on the rate
        p00, p01, p02, p11, p12, p22 = self._cov
        f2p0 = g * p00 + h * p01 + e * p02  # (P F^T) column 2
        f2p1 = g * p01 + h * p11 + e * p12
        f2p2 = g * p02 + h * p12 + e * p22
        n00 = p00 + 2.0 * dt * p01 + dt * dt * p11 + q * dt**3 / 3.0
        n01 = p01 + dt * p11 + q * dt**2 / 2.0
        n02 = f2p0 + dt * f2p1
        n11 = p11 + q * dt
        n12 = f2p1
        n22 = g * f2p0 + h * f2p1 + e * f2p2
        a, s = a + dt * v, g * a + h * v + e * s
        innovation = T - s
        gate = np.where(following, FOLLOW_GATE, JUMP_GATE)
        jump = innovation**2 > gate**2 * (n22 + r)
        self._since_jump = np.where(jump, 0.0, self._since_jump)
        if np.any(jump):  # a jump of T_a at the interval's start: variance along (1, 0, g)
            size = np.where(jump, JUMP_SIZE**2 * r, 0.0)
            n00, n02, n22 = n00 + size, n02 + g * size, n22 + g * g * size
        k0, k1, k2 = n02 / (n22 + r), n12 / (n22 + r), n22 / (n22 + r)
        a, v, s = a + k0 * innovation, v + k1 * innovation, s + k2 * innovation
        cov = (n00 - k0 * n02, n01 - k0 * n12, n02 - k0 * n22, n11 - k1 * n12, n12 - k1 * n22,
               n22 - k2 * n22)  # fmt: skip
        if not all(np.all(np.isfinite(x)) for x in (a, v, s, *cov)):
            return self._start(T, t)  # never a non-finite estimate: restart at the readings
        self._state, self._cov = (a, v, s), cov
        return np.array(a)

    def measured_temperature(self, T: FloatArray, t: float) -> FloatArray:
        """Return the estimated actuator temperatures (see :meth:`__call__`)."""
        return self(T, t)


class SensorLag(Effect):
    """First-order lag of the temperature sensor behind the actuator."""

    name: ClassVar[str] = "sensor_lag"
    summary: ClassVar[str] = "temperature sensor lags the actuator (first order, time constant tau)"
    role: ClassVar[Role] = Role.TEMPERATURE
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "tau_s", "s", 0.0, 1e9, 5.0, "sensor time constant", low_open=True, time_scaled=True
        ),
    )
    fit_parameters: ClassVar[tuple[str, ...]] = ("tau_s",)
    local_options: ClassVar[tuple[str, ...]] = ("tau_s",)
    identifiable: ClassVar[Mapping[str, Identifiable]] = {"tau_s": Identifiable.TIME_CONSTANT}
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter("temperature_lead_s", "s", 0.0, 3600.0, 0.0, "sensor lag to undo (0 = off)"),
        Parameter(
            "temperature_lead_filter_s", "s", 0.0, 3600.0, 0.5, "smoothing time of the lead"
        ),
        Parameter(
            "temperature_noise_degc", "degC", 1e-6, 10.0, 0.02, "first sensor noise sd"
        ),
    )

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return ``tau_s`` [s]."""
        return {"tau_s": float(fit.values["tau_s"])}

    def problem(self, reported: dict[str, float]) -> str | None:
        """Reject a lag <= 0."""
        if reported["tau_s"] <= 0:
            return f"lag {reported['tau_s']:.3g} s is not positive"
        return None

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Undo the fitted lag, smoothing quiet stretches over LEAD_FILTER_FRACTION of it."""
        return {
            "temperature_lead_s": reported["tau_s"],
            "temperature_lead_filter_s": LEAD_FILTER_FRACTION * reported["tau_s"],
        }

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the sensor's lag."""
        return SensorLagStage(settings["tau_s"])

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the temperature lead, or None when ``temperature_lead_s`` is 0."""
        tau, filter_s = values["temperature_lead_s"], values["temperature_lead_filter_s"]
        noise = values["temperature_noise_degc"]
        if tau == 0.0:
            return None
        if isinstance(previous, TemperatureLead):
            return previous.retuned(tau, filter_s, noise)
        return TemperatureLead(tau, filter_s, noise)
