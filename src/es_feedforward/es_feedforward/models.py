"""Forward and inverse electrostrictive models, vectorised over any array shape.

Equations: ``shared/docs/physics.md`` (thesis typos corrected). Every inverse returns the
voltage together with a per-element :class:`Status`, so that a caller can turn what happened
to each actuator into diagnostics; no inverse ever returns NaN or a voltage beyond ``v_limit``.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Final

import numpy as np
import numpy.typing as npt

from es_feedforward.params import ActuatorParams, FloatArray

#: Amplifier limit of the thesis set-up [V].
DEFAULT_V_LIMIT: Final = 350.0
#: u* = atanh(1/sqrt(3)): where the slope dz/dV of the hyperbolic model peaks.
U_STAR: Final = float(np.arctanh(1.0 / np.sqrt(3.0)))


class Status(IntEnum):
    """Per-element outcome of a model evaluation, ordered by severity."""

    OK = 0
    OUT_OF_VALIDITY = 1  # temperature outside the laws' range: evaluated at the nearest bound
    CLIPPED_LOW = 2  # set point below 0: driven to 0 V
    CLIPPED_HIGH = 3  # set point beyond what v_limit reaches (or z_sat): driven to the limit
    INVALID = 4  # non-finite input: 0 V


@dataclass(frozen=True)
class InverseResult:
    """Voltages [V] and per-element :class:`Status` codes (int8) of an inverse model."""

    voltage: FloatArray
    status: npt.NDArray[np.int8]


def clamp_temperature(
    T: npt.ArrayLike, params: ActuatorParams
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Return T clamped into the laws' validity range and a mask of elements that were outside."""
    T = np.asarray(T, np.float64)
    low, high = params.validity_range()
    clamped = np.clip(T, low, high)
    return clamped, (clamped != T) & np.isfinite(T)


def z_sat(T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return the saturation displacement M L / k^2 [m] of the hyperbolic model."""
    k = params.k(T)
    return np.asarray(params.M(T) * params.L / (k * k), np.float64)


def d_max(T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return the largest slope dz/dV = 4 M / (3 sqrt(3) k) [m/V] of the hyperbolic model."""
    return np.asarray(4.0 * params.M(T) / (3.0 * np.sqrt(3.0) * params.k(T)), np.float64)


def v_max(T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return the voltage u* L / k [V] at which the slope peaks (displacement z_sat / 3 there)."""
    return np.asarray(U_STAR * params.L / params.k(T), np.float64)


def hyperbolic_forward(V: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return z = (M L / k^2) tanh^2(k V / L) [m] (even in V)."""
    k = params.k(T)
    t = np.tanh(k * np.asarray(V, np.float64) / params.L)
    return np.asarray(params.M(T) * params.L / (k * k) * t * t, np.float64)


def hyperbolic_slope(V: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return d(V) = dz/dV = (2 M / k) tanh(u) sech^2(u), u = k V / L [m/V]."""
    k = params.k(T)
    u = k * np.asarray(V, np.float64) / params.L
    t = np.tanh(u)
    return np.asarray(2.0 * params.M(T) / k * t * (1.0 - t * t), np.float64)


def quadratic_forward(V: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return z = M V^2 / L [m] (Mason's low-field model)."""
    V = np.asarray(V, np.float64)
    return np.asarray(params.M(T) * V * V / params.L, np.float64)


def _classify(
    z: FloatArray, T: FloatArray, params: ActuatorParams
) -> tuple[FloatArray, FloatArray, npt.NDArray[np.int8]]:
    """Return (z cleaned of NaN and negatives, T clamped, initial status) for an inverse."""
    z, T = np.broadcast_arrays(np.asarray(z, np.float64), np.asarray(T, np.float64))
    finite = np.isfinite(z) & np.isfinite(T)
    T_eval, outside = clamp_temperature(np.where(finite, T, params.Tm + 10.0), params)
    status = np.where(outside, Status.OUT_OF_VALIDITY, Status.OK).astype(np.int8)
    status[z < 0.0] = Status.CLIPPED_LOW
    status[~finite] = Status.INVALID
    return np.where(finite & (z > 0.0), z, 0.0), T_eval, status


def hyperbolic_inverse(
    z: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams, v_limit: float = DEFAULT_V_LIMIT
) -> InverseResult:
    """Return V = (L / k) atanh(sqrt(z / z_sat)) with its status.

    Set points at or beyond z(v_limit, T) (which is below z_sat) give ``v_limit`` and
    ``CLIPPED_HIGH``; negative ones 0 V and ``CLIPPED_LOW``; non-finite inputs 0 V and
    ``INVALID``; temperatures outside the laws' range are clamped to it (``OUT_OF_VALIDITY``).
    """
    z_clean, T_eval, status = _classify(np.asarray(z), np.asarray(T), params)
    k = params.k(T_eval)
    M = params.M(T_eval)
    ratio = z_clean * (k * k) / (M * params.L)
    # tanh^2 of the limit argument: set points above it are not reachable within v_limit.
    t_lim = np.tanh(k * v_limit / params.L)
    ratio_lim = t_lim * t_lim
    high = ratio >= ratio_lim
    voltage = params.L / k * np.arctanh(np.sqrt(np.minimum(ratio, ratio_lim)))
    voltage = np.where(high, v_limit, voltage)
    status[high & (status < Status.CLIPPED_HIGH)] = Status.CLIPPED_HIGH
    voltage[status >= Status.CLIPPED_LOW] = np.where(
        status[status >= Status.CLIPPED_LOW] == Status.CLIPPED_HIGH, v_limit, 0.0
    )
    return InverseResult(np.asarray(voltage, np.float64), status)


def quadratic_inverse(
    z: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams, v_limit: float = DEFAULT_V_LIMIT
) -> InverseResult:
    """Return V = sqrt(z L / M) with its status (same clipping rules as the hyperbolic inverse)."""
    z_clean, T_eval, status = _classify(np.asarray(z), np.asarray(T), params)
    voltage = np.sqrt(z_clean * params.L / params.M(T_eval))
    high = voltage >= v_limit
    status[high & (status < Status.CLIPPED_HIGH)] = Status.CLIPPED_HIGH
    voltage = np.where(status == Status.CLIPPED_HIGH, v_limit, voltage)
    voltage = np.where((status == Status.CLIPPED_LOW) | (status == Status.INVALID), 0.0, voltage)
    return InverseResult(np.asarray(voltage, np.float64), status)
