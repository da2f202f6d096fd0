"""Hysteresis: a Prandtl-Ishlinskii operator on the drive, growing towards Tm.

V_eff = (1 - sum_i a_i) V + sum_i a_i play_(r_i)(V): N play operators of half-widths r_i
blended with the plain drive, a_i = weight_i exp(-(T_a - T_0) / HYSTERESIS_DECAY). The
plant takes T_0 = Tm + HYSTERESIS_ONSET (each a_i clipped to [0, 1]); the calibration takes
T_0 = the data's mean temperature. Names: operator 1 is ``weight``/``threshold_v``,
operator i > 1 ``weight_i``/``threshold_v_i`` (plant parameters, calibration results and
``compensation.hysteresis_weight[_i]``/``hysteresis_threshold_v[_i]``). The calibration
chooses N <= MAX_OPERATORS by the information criterion; given thresholds the weights enter
linearly (to first order in the weights) and are fitted non-negative with scipy's NNLS
(:func:`nonnegative_weights`, :func:`best_operators`). Feedforward: the operator's exact
inverse, per actuator with its play states (:func:`pi_inverse`).
"""

from __future__ import annotations

from itertools import combinations
from typing import ClassVar, Final

import numpy as np
from scipy.optimize import nnls

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role

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
        weights: a_i, (K,), non-negative, sum < 1.
        thresholds: r_i, (K,) [V], non-negative.

    """
    K = states.shape[0]
    shape = (K,) + (1,) * np.ndim(target)
    a = np.asarray(weights, np.float64).reshape(shape)
    r = np.asarray(thresholds, np.float64).reshape(shape)
    a0 = 1.0 - float(np.sum(weights))

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


class OperatorFitError(ValueError):
    """A normal-equation system of play-operator weights that cannot be solved."""


def nonnegative_weights(gram: FloatArray, rhs: FloatArray) -> tuple[FloatArray, float]:
    """Return the weights w >= 0 minimising w' G w - 2 b' w, and that minimum.

    ``gram`` (K, K) and ``rhs`` (K,) are the normal equations of a least-squares problem
    ||C w - r||^2 = ||r||^2 + w' G w - 2 b' w (G = C'C, b = C'r, any units): the minimum is
    the change of the sum of squares the weights bring (<= 0). Solved as the equivalent
    K x K non-negative least-squares problem ||R w - R^-T b|| (G = R'R) with scipy's NNLS,
    so the weights are non-negative by construction.

    Raises:
        OperatorFitError: shapes that do not match or values that are not finite.

    """
    G = np.asarray(gram, np.float64)
    b = np.asarray(rhs, np.float64)
    K = b.size
    if G.shape != (K, K) or K == 0:
        raise OperatorFitError(f"gram {G.shape} does not match rhs ({K},)")
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(b))):
        raise OperatorFitError("normal equations of the play weights are not finite")
    scale = np.sqrt(np.maximum(np.diag(G), 1e-300))
    Gs = G / np.outer(scale, scale) + 1e-10 * np.eye(K)
    R = np.linalg.cholesky(Gs).T  # Gs = R'R
    d = np.linalg.solve(R.T, b / scale)
    ws, _ = nnls(R, d)
    w = ws / scale
    return np.asarray(w, np.float64), float(w @ G @ w - 2.0 * b @ w)


def best_operators(
    gram: FloatArray, rhs: FloatArray, max_order: int = MAX_OPERATORS
) -> list[tuple[tuple[int, ...], FloatArray, float]]:
    """Return, for N = 1 .. ``max_order``, the N columns whose NNLS fit is best.

    ``gram`` and ``rhs`` are the normal equations over K candidate operators (e.g. a grid of
    thresholds, see :func:`nonnegative_weights`). Every subset of N columns is tried; a
    subset where NNLS zeroes a weight is a smaller one in disguise and is skipped. Each entry
    is (column indices, their weights >= 0, change of the sum of squares); an N no subset
    reaches with all weights positive is left out.

    Raises:
        OperatorFitError: as :func:`nonnegative_weights`.

    """
    K = np.asarray(rhs).size
    out: list[tuple[tuple[int, ...], FloatArray, float]] = []
    for order in range(1, min(max_order, K) + 1):
        best: tuple[tuple[int, ...], FloatArray, float] | None = None
        for subset in combinations(range(K), order):
            idx = list(subset)
            w, change = nonnegative_weights(gram[np.ix_(idx, idx)], rhs[idx])
            if np.all(w > 0) and (best is None or change < best[2]):
                best = (subset, w, change)
        if best is not None:
            out.append(best)
    return out


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
    compensation: ClassVar[tuple[Parameter, ...]] = _operator_parameters("hysteresis_", 0.9, 1000.0)

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
        """Return each operator's weight and threshold [V]."""
        return {k: float(v) for k, v in fit.values.items()}

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

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Invert the fitted operator (weights at the data's mean temperature)."""
        return {f"hysteresis_{k}": v for k, v in reported.items() if k != "decay_per_degc"}
