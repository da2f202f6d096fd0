"""Hysteresis: a Prandtl-Ishlinskii operator on the drive, growing towards Tm.

V_eff = (1 - sum_i a_i) V + sum_i a_i play_(r_i)(V): N play operators of half-widths r_i
blended with the plain drive, a_i = weight_i exp(-(T_a - T_0) / HYSTERESIS_DECAY). The
plant takes T_0 = Tm + HYSTERESIS_ONSET (each a_i clipped to [0, 1]); the calibration takes
T_0 = the data's mean temperature. Names: operator 1 is ``weight``/``threshold_v``,
operator i > 1 ``weight_i``/``threshold_v_i`` (plant parameters, calibration results and
``compensation.hysteresis_weight[_i]``/``hysteresis_threshold_v[_i]``). The calibration
chooses N <= MAX_OPERATORS by the information criterion; given thresholds the weights enter
linearly (to first order in the weights) and are fitted non-negative with scipy's NNLS
(``es_calibration.search.playfit``), with beta of
a_i = weight_i exp(-beta (T_a - T_mean)). Feedforward: the operator's exact inverse, per
actuator with its play states (:func:`pi_inverse`), the weights taken at each actuator's
temperature with the fitted beta (``compensation.hysteresis_decay_per_degc``,
``hysteresis_reference_temperature`` = T_mean).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar, Final

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role
from es_physics.effects.stages import Compensator, PlantContext, PlantStage, StepState

#: Hysteresis weight a = a0 exp(-(T_a - Tm - HYSTERESIS_ONSET) / HYSTERESIS_DECAY) [degC].
HYSTERESIS_ONSET: Final = 2.0
HYSTERESIS_DECAY: Final = 4.0
#: Most play operators the simulator, the calibration and the compensation use.
MAX_OPERATORS: Final = 3
#: Steepest temperature law of the weights the calibration accepts [1/degC].
MAX_DECAY_PER_DEGC: Final = 2.0


def hysteresis_weight(T: FloatArray, Tm: float | FloatArray, weight: float) -> FloatArray:
    """Return a = weight exp(-(T - Tm - 2) / 4), clipped to [0, 1] (T, Tm [degC])."""
    a = weight * np.exp(-(T - Tm - HYSTERESIS_ONSET) / HYSTERESIS_DECAY)
    return np.asarray(np.clip(a, 0.0, 1.0), np.float64)


def play(previous: FloatArray, V: FloatArray, threshold: float) -> FloatArray:
    """Return the backlash (play) operator output for input V [V] given its previous output."""
    return np.asarray(np.clip(previous, V - threshold, V + threshold), np.float64)


def operator_names(index: int) -> tuple[str, str]:
    """Return the (weight, threshold) parameter names of operator ``index`` (0-based)."""
    suffix = "" if index == 0 else f"_{index + 1}"
    return f"weight{suffix}", f"threshold_v{suffix}"


def pi_inverse(
    target: FloatArray, states: FloatArray, weights: FloatArray, thresholds: FloatArray
) -> FloatArray:
    """Return the V that makes (1 - sum a_i) V + sum a_i play_(r_i)(V) equal ``target``.

    Exact for the operators' current ``states``: the output is a continuous, piecewise linear,
    increasing function of V (sum a_i < 1) whose slope changes only where an operator starts
    to move (V = state_i +- r_i), and is 1 outside all of them. The outputs at the 2K
    breakpoints are computed for every actuator at once and the target's segment inverted,
    so the inverse of the whole Prandtl-Ishlinskii operator follows step by step with the
    memory of the voltages actually applied (vectorised over the grid).

    Args:
        target: wanted V_eff, shape S [V].
        states: play outputs before this step, (K, *S) [V].
        weights: a_i, (K,) or per element (K, *S), non-negative, summing to < 1.
        thresholds: r_i, (K,) [V], non-negative.

    """
    K = states.shape[0]
    shape = (K,) + (1,) * np.ndim(target)
    a = np.asarray(weights, np.float64)
    a = a.reshape(shape) if a.ndim == 1 else a
    r = np.asarray(thresholds, np.float64).reshape(shape)
    a0 = 1.0 - np.sum(a, axis=0)

    def output(V: FloatArray) -> FloatArray:
        return np.asarray(a0 * V + np.sum(a * np.clip(states, V - r, V + r), axis=0), np.float64)

    breaks = np.sort(np.concatenate([states - r, states + r], axis=0), axis=0)  # (2K, *S)
    outs = np.stack([output(b) for b in breaks])
    j = np.clip(np.sum(outs <= target, axis=0) - 1, 0, 2 * K - 2)[None]
    lo_b, hi_b = (np.take_along_axis(breaks, j + k, axis=0)[0] for k in (0, 1))
    lo_o, hi_o = (np.take_along_axis(outs, j + k, axis=0)[0] for k in (0, 1))
    span = hi_o - lo_o
    frac = np.where(span > 0, (target - lo_o) / np.where(span > 0, span, 1.0), 0.0)
    inside = lo_b + frac * (hi_b - lo_b)
    # beyond the outer breakpoints every operator moves with V: slope 1
    V = np.where(
        target <= outs[0],
        breaks[0] + (target - outs[0]),
        np.where(target >= outs[-1], breaks[-1] + (target - outs[-1]), inside),
    )
    return np.asarray(V, np.float64)


class HysteresisStage(PlantStage):
    """The plant's Prandtl-Ishlinskii operator: operator 1 always, further ones if weighted.

    Rate independent, so with one switch of the applied voltage per plant step each play
    state changes at most twice per step and is evaluated exactly.
    """

    def __init__(self, operators: list[tuple[float, float]], shape: tuple[int, int]) -> None:
        self._operators = operators
        self._play = np.zeros((len(operators), *shape))

    def drive(self, voltage: FloatArray, step: StepState) -> FloatArray:
        """Return (1 - sum a_i) V + sum a_i play_(r_i)(V), a_i at the actuator temperature."""
        total: FloatArray | float = 0.0
        mix: FloatArray | float = 0.0
        before, after = step.drive.before, step.drive.after
        for k, (weight, threshold) in enumerate(self._operators):
            first = play(self._play[k], before, threshold)
            second = play(first, after, threshold)
            self._play[k] = second
            a = hysteresis_weight(step.T, step.params.Tm, weight)
            played = np.where(step.before_switch, first, second)
            total, mix = (a, a * played) if k == 0 else (total + a, mix + a * played)
        return np.asarray((1.0 - total) * voltage + mix, np.float64)


#: Largest sum of hysteresis weights the inverse uses (its slope 1 - sum stays >= 0.1).
MAX_WEIGHT_SUM: Final = 0.9


class HysteresisInverse(Compensator):
    """Exact inverse of V_eff = (1 - sum a_i) V + sum a_i play_(r_i)(V) on a grid.

    One play state per operator and actuator, (K, *shape); the inverse is :func:`pi_inverse`
    (with one operator: if the play stays, V = (V_eff - a p) / (1 - a); pushed up,
    V = V_eff + a r; pushed down, V = V_eff - a r). The states are updated with the voltage
    actually applied. Given the actuators' temperatures T [degC], the weights are
    a_i = weight_i exp(-beta (T - T_ref)) per actuator (scaled down where they would sum to
    more than ``MAX_WEIGHT_SUM``); without, as given. In the feedforward's chain T is the
    temperature the law is evaluated at for the command (:meth:`law_temperature`).
    """

    reshapes_drive = True

    def __init__(
        self,
        weights: float | Sequence[float],
        thresholds: float | Sequence[float],
        shape: tuple[int, ...],
        decay_per_degc: float = 0.0,
        reference_temperature: float = 46.0,
    ) -> None:
        w = np.atleast_1d(np.asarray(weights, np.float64))
        r = np.atleast_1d(np.asarray(thresholds, np.float64))
        use = w > 0.0
        self.weights, self.thresholds = w[use], r[use]
        self.shape = shape
        self.decay_per_degc = decay_per_degc
        self.reference_temperature = reference_temperature
        self.play = np.zeros((self.weights.size, *shape))
        self._T: FloatArray | None = None

    def weights_at(self, T: FloatArray | None) -> FloatArray:
        """Return the weights (K,) as given, or (K, *T.shape) at temperatures ``T`` [degC]."""
        if T is None or self.decay_per_degc == 0.0:
            return self.weights
        above = np.asarray(T, np.float64) - self.reference_temperature
        factor = np.exp(-self.decay_per_degc * above)
        a = self.weights.reshape((-1,) + (1,) * factor.ndim) * factor
        total = a.sum(axis=0)
        return np.asarray(
            a * np.where(total > MAX_WEIGHT_SUM, MAX_WEIGHT_SUM / np.maximum(total, 1e-300), 1.0),
            np.float64,
        )

    @property
    def active(self) -> bool:
        """Whether the operator does anything."""
        return self.weights.size > 0

    def retuned(
        self,
        weights: float | Sequence[float],
        thresholds: float | Sequence[float],
        decay_per_degc: float = 0.0,
        reference_temperature: float = 46.0,
    ) -> HysteresisInverse:
        """Return a copy with new parameters and this one's play states (this one unchanged).

        Operators carry their state by position; a new operator starts from the first one's
        state (or 0).
        """
        other = HysteresisInverse(
            weights, thresholds, self.shape, decay_per_degc, reference_temperature
        )
        for k in range(other.weights.size):
            if k < self.weights.size:
                other.play[k] = self.play[k]
            elif self.weights.size:
                other.play[k] = self.play[0]
        return other

    def start_from(self, voltage: FloatArray) -> None:
        """Set every play state to ``voltage`` [V] (bumpless start)."""
        self.play = np.broadcast_to(voltage, self.play.shape).copy()

    def invert(self, v_eff: FloatArray, T: FloatArray | None = None) -> FloatArray:
        """Return the voltage [V] that makes the operator output ``v_eff`` (at temperatures T)."""
        if not self.active:
            return v_eff
        return pi_inverse(v_eff, self.play, self.weights_at(T), self.thresholds)

    def apply(self, voltage: FloatArray) -> None:
        """Advance the play states with the voltage [V] that was actually sent."""
        if self.active:
            r = self.thresholds.reshape((-1,) + (1,) * voltage.ndim)
            self.play = np.clip(self.play, voltage - r, voltage + r)

    def output(self, voltage: FloatArray, T: FloatArray | None = None) -> FloatArray:
        """Return the operator's output for ``voltage`` once :meth:`apply` has taken it [V]."""
        if not self.active:
            return voltage
        w = self.weights_at(T)
        if w.ndim == 1:
            w = w.reshape((-1,) + (1,) * voltage.ndim)
        return np.asarray((1.0 - w.sum(axis=0)) * voltage + (w * self.play).sum(0), np.float64)

    def law_temperature(self, T: FloatArray, t: float) -> FloatArray:
        """Keep the temperatures [degC] the weights are taken at for this command."""
        self._T = T
        return T

    def invert_drive(self, voltage: FloatArray, t: float) -> FloatArray:
        """Return the drive through the operator's inverse (see :meth:`invert`)."""
        return self.invert(voltage, self._T)

    def commit(self, sent: FloatArray, drive: FloatArray, t: float) -> FloatArray:
        """Advance the play states with ``drive`` and return the operator's output."""
        self.apply(drive)
        return self.output(drive, self._T)


def compensated_operators(
    values: Mapping[str, float],
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Return the (weights, thresholds [V]) of the compensation's operators in use."""
    pairs = [
        (values[f"hysteresis_{w}"], values[f"hysteresis_{r}"])
        for w, r in (operator_names(i) for i in range(MAX_OPERATORS))
    ]
    used = [(w, r) for w, r in pairs if w > 0.0]
    return tuple(w for w, _ in used), tuple(r for _, r in used)


def _operator_parameters(prefix: str, high_weight: float, high_r: float) -> tuple[Parameter, ...]:
    out: list[Parameter] = []
    for i in range(MAX_OPERATORS):
        weight, threshold = operator_names(i)
        first = i == 0 and not prefix
        out.append(
            Parameter(
                f"{prefix}{weight}",
                "",
                0.0,
                high_weight,
                0.1 if first else 0.0,
                f"blend weight a_{i + 1}" + ("" if prefix else " at Tm + 2 degC"),
            )
        )
        out.append(
            Parameter(
                f"{prefix}{threshold}",
                "V",
                0.0,
                high_r,
                30.0 if first else 0.0,
                f"play operator {i + 1}'s half-width r_{i + 1}",
            )
        )
    return tuple(out)


class Hysteresis(Effect):
    """Prandtl-Ishlinskii hysteresis on the drive voltage (N play operators)."""

    name: ClassVar[str] = "hysteresis"
    summary: ClassVar[str] = "N play operators (half-widths r_i) blended with the drive, a_i(T)"
    role: ClassVar[Role] = Role.PLAY
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = _operator_parameters("", 1.0, 1e4)
    fit_parameters: ClassVar[tuple[str, ...]] = ("weight", "decay_per_degc")
    searched: ClassVar[tuple[str, ...]] = ("threshold_v",)
    max_order: ClassVar[int] = MAX_OPERATORS
    compensation: ClassVar[tuple[Parameter, ...]] = (
        *_operator_parameters("hysteresis_", 0.9, 1000.0),
        Parameter(
            "hysteresis_decay_per_degc",
            "1/degC",
            -MAX_DECAY_PER_DEGC,
            MAX_DECAY_PER_DEGC,
            0.0,
            "beta of the weights' law exp(-beta (T - T_ref)) (0 = no temperature law)",
        ),
        Parameter(
            "hysteresis_reference_temperature",
            "degC",
            -50.0,
            150.0,
            46.0,
            "T_ref, where the weights hold as given",
        ),
    )

    def fit_names(self, order: int = 1) -> tuple[str, ...]:
        """Return ``weight``, ``weight_2``, ... for ``order`` operators, then ``decay_per_degc``.

        ``decay_per_degc`` is beta of the weights' temperature law exp(-beta (T - T_mean))
        (the simulator's is 1 / HYSTERESIS_DECAY; a stand's hysteresis may not vary at all).
        """
        return (*(operator_names(i)[0] for i in range(order)), "decay_per_degc")

    def starts(self, duration_s: float) -> list[dict[str, float]]:
        """Start beta at the simulator's value (the weights start at 0)."""
        return [{"decay_per_degc": 1.0 / HYSTERESIS_DECAY}]

    def searched_names(self, order: int = 1) -> tuple[str, ...]:
        """Return ``threshold_v``, ``threshold_v_2``, ... for ``order`` operators."""
        return tuple(operator_names(i)[1] for i in range(order))

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return each operator's weight and threshold [V], beta and T_mean [degC]."""
        values = {k: float(v) for k, v in fit.values.items()}
        return {**values, "reference_temperature": float(fit.mean_temperature)}

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Return the weights' uncertainties (the thresholds are scanned)."""
        return {k: float(v) for k, v in fit.sigma.items() if k.startswith("weight")}

    def problem(self, reported: dict[str, float]) -> str | None:
        """Reject weights outside (0, 1) or summing to 1 or more, or a steep beta."""
        if abs(reported["decay_per_degc"]) > MAX_DECAY_PER_DEGC:
            return f"decay_per_degc {reported['decay_per_degc']:.3g} beyond +-{MAX_DECAY_PER_DEGC}"
        weights = {k: v for k, v in reported.items() if k.startswith("weight")}
        for k, v in weights.items():
            if not 0.0 < v < 1.0:
                return f"{k} {v:.3g} outside (0, 1)"
        if sum(weights.values()) >= 1.0:
            return f"weights sum to {sum(weights.values()):.3g} >= 1"
        return None

    def undetermined(self, fit: FittedEffect) -> str | None:
        """Reject a weight not known to better than 100 % at 1 sigma.

        Such an operator is one the data cannot tell from none: its cut of the error comes
        from the law refitted beside it (on the independent stand: a thermal gradient taken
        by an operator of weight 2e-4 +- 4e-4 at the drive's top).
        """
        for key, value in fit.values.items():
            if key.startswith("weight") and key in fit.sigma and not fit.sigma[key] < abs(value):
                return f"{key} not determined (1-sigma {fit.sigma[key]:.3g})"
        return None

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Invert the fitted operator, its weights following the fitted temperature law."""
        return {f"hysteresis_{k}": v for k, v in reported.items()}

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the plant's operator (operator 1 always, further ones where weighted)."""
        operators = [
            (settings[w], settings[r])
            for k, (w, r) in enumerate(operator_names(i) for i in range(MAX_OPERATORS))
            if k == 0 or settings[w] > 0.0
        ]
        return HysteresisStage(operators, context.shape)

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the operator's inverse, or None when no weight is > 0.

        A new inverse replacing none starts from the command in force (bumpless).
        """
        weights, thresholds = compensated_operators(values)
        if not weights:
            return None
        law = (values["hysteresis_decay_per_degc"], values["hysteresis_reference_temperature"])
        if isinstance(previous, HysteresisInverse):
            return previous.retuned(weights, thresholds, *law)
        inverse = HysteresisInverse(weights, thresholds, shape, *law)
        if last_voltage is not None:
            inverse.start_from(np.array(last_voltage))
        return inverse
