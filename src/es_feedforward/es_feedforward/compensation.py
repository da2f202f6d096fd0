"""Compensation of the effects beyond the basic model (pure numpy/scipy, no rclpy).

One definition per effect, shared with the simulator and the calibration tool
(``docs/architecture.md``, "Effects beyond the basic model"). The feedforward applies them
around the model inverse:

1. temperature lead (``sensor_lag``): T_used = T + tau dT/dt, derivative low-pass filtered;
2. delay: set point predicted ``delay_s`` ahead from the slope of the last two set points;
3. thermal expansion: alpha (T_used - T_ref) subtracted from the set point;
4. drift: set point divided by 1 - a (1 - exp(-(t / tau)^nu)) (z is proportional to M);
5. coupling: (I + c lap) z_free = z_ref solved with a sparse LU factorised once per grid;
6. frequency dispersion: exact inverse of the first-order relaxation
   V_law = V_pi - r D (V_pi - s) at the end of the command interval (per-actuator states);
7. hysteresis: exact inverse of the Prandtl-Ishlinskii operator
   V_pi = (1 - sum a_i) V + sum a_i play_(r_i)(V), per-actuator play states.

Self-heating moves the temperature the law is evaluated at: T_used + dT, dT the excess the
drive sent causes (:class:`es_physics.effects.self_heating.HeatingEstimate`, in feedforward).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Final

import numpy as np
from scipy.sparse import csc_matrix, diags, identity
from scipy.sparse.linalg import splu

from es_feedforward.errors import FeedforwardConfigError
from es_physics.effects import registry
from es_physics.effects.frequency_dispersion import (
    relaxation_advance,
    relaxation_decay,
    relaxation_inverse,
)
from es_physics.effects.hysteresis import pi_inverse
from es_physics.params import FloatArray

#: Name prefix of the compensation parameters (ROS parameters and parameter files).
PREFIX: Final = "compensation."


@dataclass(frozen=True)
class CompensationParams:
    """The ``compensation.*`` parameters; every effect is off at its default.

    The fields are the typed face of the compensation parameters that the effects of
    :mod:`es_physics.effects` declare (names, ranges and defaults are theirs; a test checks
    that the two agree).

    Attributes:
        temperature_lead_s: sensor lag tau to undo [s] (0 = off).
        temperature_lead_filter_s: time constant of the derivative's low-pass [s].
        delay_s: transport delay to predict over [s] (0 = off).
        hysteresis_weight: weight a of the play operator, in [0, 0.9] (0 = off).
        hysteresis_threshold_v: half-width r of the play operator [V].
        hysteresis_weight_2, hysteresis_threshold_v_2, hysteresis_weight_3,
        hysteresis_threshold_v_3: the second and third operators of a Prandtl-Ishlinskii
            hysteresis (weight 0 = unused).
        coupling: coefficient c of the 4-neighbour Laplacian coupling (0 = off).
        thermal_expansion: expansion coefficient alpha [m/degC] (0 = off).
        expansion_reference_temperature: temperature of zero expansion [degC].
        drift_fraction: final relative loss a of M (0 = off).
        drift_tau_s: drift time constant tau [s].
        drift_nu: stretching exponent nu of the drift.
        drift_epoch_s: ROS time [s] at which the drift started (t = now - epoch).
        dispersion_fraction: relaxing fraction r of the gain (0 = off).
        dispersion_corner_hz: relaxation corner frequency f_c [Hz].
        self_heating_gain: excess actuator temperature per drive power measure
            [degC s/V^2] (0 = off).
        self_heating_tau_s: time constant of the excess temperature [s].
        self_heating_mean_window_s: running-mean window of the drive [s].

    """

    temperature_lead_s: float = 0.0
    temperature_lead_filter_s: float = 0.5
    delay_s: float = 0.0
    hysteresis_weight: float = 0.0
    hysteresis_threshold_v: float = 0.0
    hysteresis_weight_2: float = 0.0
    hysteresis_threshold_v_2: float = 0.0
    hysteresis_weight_3: float = 0.0
    hysteresis_threshold_v_3: float = 0.0
    coupling: float = 0.0
    thermal_expansion: float = 0.0
    expansion_reference_temperature: float = 46.0
    drift_fraction: float = 0.0
    drift_tau_s: float = 3600.0
    drift_nu: float = 1.0
    drift_epoch_s: float = 0.0
    dispersion_fraction: float = 0.0
    dispersion_corner_hz: float = 20.0
    self_heating_gain: float = 0.0
    self_heating_tau_s: float = 1.0
    self_heating_mean_window_s: float = 1.0

    @classmethod
    def from_mapping(cls, values: dict[str, float]) -> CompensationParams:
        """Build from ``{name: value}`` with or without the ``compensation.`` prefix.

        Raises:
            FeedforwardConfigError: an unknown name or a value outside its range
                (see :data:`RANGES`).

        """
        known = {f.name for f in fields(cls)}
        kwargs: dict[str, float] = {}
        for key, value in values.items():
            name = key.removeprefix(PREFIX)
            if name not in known:
                raise FeedforwardConfigError(f"unknown compensation parameter {key!r}")
            kwargs[name] = float(value)
        params = cls(**kwargs)
        reason = params.reason_to_reject()
        if reason is not None:
            raise FeedforwardConfigError(reason)
        return params

    def reason_to_reject(self) -> str | None:
        """Return why this set is not usable, or ``None``."""
        for name, (low, high) in RANGES.items():
            value = getattr(self, name)
            if not low <= value <= high:  # NaN fails too
                return f"{PREFIX}{name}={value!r} is outside [{low}, {high}]"
        if self.drift_fraction > 0.0 and self.drift_tau_s <= 0.0:
            return f"{PREFIX}drift_tau_s must be > 0 when drift_fraction > 0"
        if sum(self.hysteresis_operators()[0]) > 0.9:
            return f"{PREFIX}hysteresis weights sum to more than 0.9"
        return None

    def hysteresis_operators(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Return the (weights, thresholds [V]) of the hysteresis operators in use."""
        pairs = [
            (self.hysteresis_weight, self.hysteresis_threshold_v),
            (self.hysteresis_weight_2, self.hysteresis_threshold_v_2),
            (self.hysteresis_weight_3, self.hysteresis_threshold_v_3),
        ]
        used = [(w, r) for w, r in pairs if w > 0.0]
        return tuple(w for w, _ in used), tuple(r for _, r in used)


#: Accepted range of every compensation parameter (inclusive), from the effect registry.
RANGES: Final[dict[str, tuple[float, float]]] = {
    p.name: (p.low, p.high) for effect in registry().values() for p in effect.compensation
}
#: One line per compensation parameter: the declaring effect, what it is, its unit.
DESCRIPTIONS: Final[dict[str, str]] = {
    p.name: f"{effect.name}: {p.doc}" + (f" [{p.unit}]" if p.unit else "")
    for effect in registry().values()
    for p in effect.compensation
}


class TemperatureLead:
    """T_used = T + tau dT/dt with a first-order low-pass on the finite-difference derivative."""

    def __init__(self, tau_s: float, filter_s: float) -> None:
        self.tau_s = tau_s
        self.filter_s = filter_s
        self._last: tuple[FloatArray, float] | None = None
        self._rate: FloatArray | None = None

    def retuned(self, tau_s: float, filter_s: float) -> TemperatureLead:
        """Return a copy with new parameters and this one's state (this one is unchanged)."""
        other = TemperatureLead(tau_s, filter_s)
        other._last, other._rate = self._last, self._rate
        return other

    def __call__(self, T: FloatArray, t: float) -> FloatArray:
        """Return the lead-corrected temperatures for a sample ``T`` taken at ``t`` [s]."""
        if self.tau_s == 0.0:
            return T
        if self._last is None or self._rate is None or self._last[0].shape != T.shape:
            self._rate = np.zeros_like(T)
        else:
            T_prev, t_prev = self._last
            dt = t - t_prev
            if dt > 0.0:
                raw = (T - T_prev) / dt
                gain = dt / (dt + self.filter_s)
                rate = self._rate + gain * (raw - self._rate)
                self._rate = np.where(np.isfinite(rate), rate, 0.0)
        self._last = (T, t)
        return np.asarray(T + self.tau_s * self._rate, np.float64)


class DelayPredictor:
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
        """Return the predicted set points (never below 0 where ``z`` is not)."""
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


def drift_factor(params: CompensationParams, t: float) -> float:
    """Return M_eff / M = 1 - a (1 - exp(-(t_rel / tau)^nu)) at ROS time ``t`` [s]."""
    if params.drift_fraction == 0.0:
        return 1.0
    t_rel = max(t - params.drift_epoch_s, 0.0)
    decay = float(np.exp(-((t_rel / params.drift_tau_s) ** params.drift_nu)))
    return 1.0 - params.drift_fraction * (1.0 - decay)


def laplacian(shape: tuple[int, int]) -> csc_matrix:
    """Return the 4-neighbour Laplacian of a row-major grid (edges: existing neighbours only)."""
    rows, cols = shape
    size = rows * cols
    index = np.arange(size).reshape(shape)
    pairs = [
        (index[:, :-1].ravel(), index[:, 1:].ravel()),
        (index[:-1, :].ravel(), index[1:, :].ravel()),
    ]
    i = np.concatenate([p[0] for p in pairs] + [p[1] for p in pairs])
    j = np.concatenate([p[1] for p in pairs] + [p[0] for p in pairs])
    adjacency = csc_matrix((np.ones(i.size), (i, j)), shape=(size, size))
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    return csc_matrix(adjacency - diags(degree))


class CouplingInverse:
    """Solve (I + c lap) z_free = z_ref for a grid; the LU factorisation is done once."""

    def __init__(self, coefficient: float, shape: tuple[int, int]) -> None:
        self.coefficient = coefficient
        self.shape = shape
        self._lu = (
            splu(csc_matrix(identity(shape[0] * shape[1]) + coefficient * laplacian(shape)))
            if coefficient != 0.0
            else None
        )

    def __call__(self, z_ref: FloatArray) -> FloatArray:
        """Return z_free for the set points ``z_ref`` (grid of ``shape``)."""
        if self._lu is None:
            return z_ref
        return np.asarray(self._lu.solve(z_ref.ravel()).reshape(self.shape), np.float64)


class HysteresisInverse:
    """Exact inverse of V_eff = (1 - sum a_i) V + sum a_i play_(r_i)(V) on a grid.

    One play state per operator and actuator, (K, *shape); the inverse is
    :func:`es_physics.effects.hysteresis.pi_inverse` (with one operator: if the play stays,
    V = (V_eff - a p) / (1 - a); pushed up, V = V_eff + a r; pushed down, V = V_eff - a r).
    The states are updated with the voltage actually applied.
    """

    def __init__(
        self,
        weights: float | Sequence[float],
        thresholds: float | Sequence[float],
        shape: tuple[int, ...],
    ) -> None:
        w = np.atleast_1d(np.asarray(weights, np.float64))
        r = np.atleast_1d(np.asarray(thresholds, np.float64))
        use = w > 0.0
        self.weights, self.thresholds = w[use], r[use]
        self.shape = shape
        self.play = np.zeros((self.weights.size, *shape))

    @property
    def active(self) -> bool:
        """Whether the operator does anything."""
        return self.weights.size > 0

    def retuned(
        self, weights: float | Sequence[float], thresholds: float | Sequence[float]
    ) -> HysteresisInverse:
        """Return a copy with new parameters and this one's play states (this one unchanged).

        Operators carry their state by position; a new operator starts from the first one's
        state (or 0).
        """
        other = HysteresisInverse(weights, thresholds, self.shape)
        for k in range(other.weights.size):
            if k < self.weights.size:
                other.play[k] = self.play[k]
            elif self.weights.size:
                other.play[k] = self.play[0]
        return other

    def start_from(self, voltage: FloatArray) -> None:
        """Set every play state to ``voltage`` (bumpless start)."""
        self.play = np.broadcast_to(voltage, self.play.shape).copy()

    def invert(self, v_eff: FloatArray) -> FloatArray:
        """Return the voltage that makes the operator output ``v_eff``."""
        if not self.active:
            return v_eff
        return pi_inverse(v_eff, self.play, self.weights, self.thresholds)

    def apply(self, voltage: FloatArray) -> None:
        """Advance the play states with the voltage that was actually sent."""
        if self.active:
            r = self.thresholds.reshape((-1,) + (1,) * voltage.ndim)
            self.play = np.clip(self.play, voltage - r, voltage + r)

    def output(self, voltage: FloatArray) -> FloatArray:
        """Return the operator's output for ``voltage`` once :meth:`apply` has taken it [V]."""
        if not self.active:
            return voltage
        w = self.weights.reshape((-1,) + (1,) * voltage.ndim)
        return np.asarray((1.0 - self.weights.sum()) * voltage + (w * self.play).sum(0), np.float64)


class RelaxationInverse:
    """Exact inverse of the drive's first-order relaxation (effect ``frequency_dispersion``).

    V_out = V - r D (V - s) at the end of a command interval h (D = exp(-2 pi f_c h), h taken
    as the last interval), ds/dt = 2 pi f_c (V - s) with the drive held between commands;
    per-actuator states s [V] (``shape``), advanced with the drive actually sent.
    """

    def __init__(self, fraction: float, corner_hz: float, shape: tuple[int, ...]) -> None:
        self.fraction = fraction
        self.corner_hz = corner_hz
        self.state: FloatArray | None = None
        self.shape = shape
        self._last: tuple[FloatArray, float] | None = None
        self._interval = 0.0

    @property
    def active(self) -> bool:
        """Whether the relaxation does anything."""
        return self.fraction > 0.0

    def retuned(self, fraction: float, corner_hz: float) -> RelaxationInverse:
        """Return a copy with new parameters and this one's state (this one is unchanged)."""
        other = RelaxationInverse(fraction, corner_hz, self.shape)
        other.state, other._last, other._interval = self.state, self._last, self._interval
        return other

    def _state_at(self, t: float) -> FloatArray | None:
        """Return the state at time ``t`` [s]: the last drive held since it was sent."""
        if self._last is None or self.state is None:
            return None
        drive, sent = self._last
        if t <= sent:
            return self.state
        return relaxation_advance(drive, self.state, relaxation_decay(self.corner_hz, t - sent))

    def invert(self, v_out: FloatArray, t: float) -> FloatArray:
        """Return the drive sent at ``t`` [s] that makes the output ``v_out`` [V] an interval on.

        Before any drive was sent the state starts at ``v_out`` (bumpless: drive = v_out).
        """
        state = self._state_at(t)
        if not self.active or state is None:
            return v_out
        decay = relaxation_decay(self.corner_hz, self._interval)
        return relaxation_inverse(v_out, state, self.fraction, decay)

    def apply(self, drive: FloatArray, t: float) -> None:
        """Advance the state to ``t`` [s] and hold ``drive`` [V] (the voltage sent) from then."""
        state = self._state_at(t)
        if self._last is not None and t > self._last[1]:
            self._interval = t - self._last[1]
        self.state = np.array(drive, np.float64) if state is None else state
        self._last = (np.array(drive, np.float64), t)
