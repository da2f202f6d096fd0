"""Polynomial (truncated even series) electrostrictive model with a numeric inverse.

z = (M V^2 / L) (1 - (2/3) u^2 + (17/45) u^4 - (62/315) u^6 + ...), u = k V / L: the Taylor
series of the hyperbolic model z_sat tanh^2(u), truncated at a selectable even order in V
(order 2 is Mason's quadratic model). With s = u^2 it reads z = z_sat g(s), g(s) = sum a_j s^j.
The series converges for u < pi/2; a truncation with a negative last term peaks at some u and
is only invertible below that peak, so the inverse's domain is s <= min(s_peak, (q v_limit)^2).
The inverse is a vectorised safeguarded Newton iteration (bisection fallback) on g(s) = z/z_sat.
"""

from __future__ import annotations

from fractions import Fraction
from functools import cache
from typing import Final

import numpy as np
import numpy.typing as npt

from es_physics.laws import (
    CODE_CLIPPED_HIGH,
    DEFAULT_V_LIMIT,
    RATIO_CAP,
    InverseResult,
    LawsAtTemperature,
    broadcast_shape,
    clean_inputs,
    laws_at,
    limit_voltages,
)
from es_physics.params import ActuatorParams, FloatArray

#: Highest supported order (power of V) of the truncated series.
MAX_ORDER: Final = 20
#: Default order: the terms the thesis prints (up to V^8).
DEFAULT_ORDER: Final = 8
_MAX_NEWTON_STEPS: Final = 100


def _bernoulli(count: int) -> list[Fraction]:
    """Return the Bernoulli numbers B_0 .. B_{count-1} (B_1 = -1/2), exactly."""
    numbers: list[Fraction] = []
    for m in range(count):
        total = Fraction(0)
        for j in range(m):
            total += Fraction(_binomial(m + 1, j)) * numbers[j]
        numbers.append(Fraction(1) if m == 0 else -total / (m + 1))
    return numbers


def _binomial(n: int, k: int) -> int:
    out = 1
    for i in range(k):
        out = out * (n - i) // (i + 1)
    return out


@cache
def series_coefficients(order: int) -> tuple[float, ...]:
    """Return a_1 .. a_N (N = order / 2) of tanh^2(y) = sum a_j y^(2j): 1, -2/3, 17/45, ...

    Raises:
        ValueError: ``order`` is not an even number in [2, MAX_ORDER].

    """
    if order % 2 or not 2 <= order <= MAX_ORDER:
        raise ValueError(f"series order must be even and in [2, {MAX_ORDER}], got {order}")
    terms = order // 2
    bern = _bernoulli(2 * terms + 3)
    factorial = [1]
    for i in range(1, 2 * terms + 3):
        factorial.append(factorial[-1] * i)
    coefficients = []
    for j in range(1, terms + 1):
        # tanh y = sum c_n y^(2n-1), c_n = 2^2n (2^2n - 1) B_2n / (2n)!; tanh^2 = 1 - tanh'
        n = j + 1
        c_n = Fraction(4**n * (4**n - 1)) * bern[2 * n] / factorial[2 * n]
        coefficients.append(float(-c_n * (2 * j + 1)))
    return tuple(coefficients)


@cache
def peak_s(order: int) -> float:
    """Return the smallest s = u^2 > 0 where the truncated g(s) stops rising (inf if never)."""
    a = series_coefficients(order)
    # g'(s) = sum j a_j s^(j-1); np.roots wants the highest power first
    derivative = [j * a[j - 1] for j in range(len(a), 0, -1)]
    if len(derivative) == 1:
        return float("inf")
    roots = np.roots(derivative)
    real = roots[(np.abs(roots.imag) < 1e-12) & (roots.real > 0.0)].real
    return float(real.min()) if real.size else float("inf")


def _g(s: FloatArray, a: tuple[float, ...]) -> FloatArray:
    """Return g(s) = sum a_j s^j (Horner)."""
    acc = np.full_like(s, a[-1])
    for coefficient in a[-2::-1]:
        acc = acc * s + coefficient
    return acc * s


def _g_prime(s: FloatArray, a: tuple[float, ...]) -> FloatArray:
    """Return g'(s) = sum j a_j s^(j-1) (Horner)."""
    count = len(a)
    acc = np.full_like(s, count * a[-1])
    for j in range(count - 1, 0, -1):
        acc = acc * s + j * a[j - 1]
    return acc


class PolynomialModel:
    """The series model of one order: forward, slope and numeric inverse."""

    def __init__(self, order: int = DEFAULT_ORDER) -> None:
        self.order = order
        self.coefficients = series_coefficients(order)
        self.peak_s = peak_s(order)

    def forward_at(self, laws: LawsAtTemperature, V: npt.ArrayLike) -> FloatArray:
        """Return z = z_sat g((q V)^2) [m]."""
        u = laws.q * np.asarray(V, np.float64)
        return np.asarray(_g(np.asarray(u * u), self.coefficients) / laws.inv_zsat, np.float64)

    def slope_at(self, laws: LawsAtTemperature, V: npt.ArrayLike) -> FloatArray:
        """Return dz/dV = 2 (M / L) V g'((q V)^2) [m/V]."""
        V = np.asarray(V, np.float64)
        u = laws.q * V
        return np.asarray(2.0 * laws.n * V * _g_prime(np.asarray(u * u), self.coefficients))

    def inverse_at(
        self, laws: LawsAtTemperature, z: npt.ArrayLike, v_limit: float
    ) -> InverseResult:
        """Solve z_sat g(s) = z for V = sqrt(s) / q, with statuses like the hyperbolic inverse.

        Set points at or beyond the reach of the series (its peak or ``v_limit``) give the
        voltage of that reach and ``CLIPPED_HIGH``.
        """
        ratio = np.multiply(z, laws.inv_zsat, out=np.empty(laws.q.shape))
        status = laws.status.copy()
        ratio, status, _ = clean_inputs(ratio, status, cap=np.inf)
        a = self.coefficients
        qv = laws.q * v_limit
        s_reach = np.minimum(self.peak_s, qv * qv)
        beyond = ratio >= _g(s_reach, a)
        status[beyond & (status < CODE_CLIPPED_HIGH)] = CODE_CLIPPED_HIGH
        target = np.where(beyond, 0.0, ratio)
        s = self._solve(target, s_reach)
        s = np.where(beyond, s_reach, s)
        voltage = np.asarray(np.sqrt(s) / laws.q, np.float64)
        return limit_voltages(voltage, status, v_limit)

    def _solve(self, target: FloatArray, s_high: FloatArray) -> FloatArray:
        """Return s in [0, s_high] with g(s) = target (g rising there), to full precision."""
        a = self.coefficients
        # the hyperbolic solution is an excellent first guess below u ~ 1
        guess = np.arctanh(np.sqrt(np.minimum(target, RATIO_CAP)))
        s = np.clip(guess * guess, 0.0, s_high)
        low = np.zeros_like(s)
        high = np.array(s_high, np.float64)
        for _ in range(_MAX_NEWTON_STEPS):
            residual = _g(s, a) - target
            low = np.where(residual <= 0.0, s, low)
            high = np.where(residual >= 0.0, s, high)
            slope = _g_prime(s, a)
            with np.errstate(divide="ignore", invalid="ignore"):
                newton = s - residual / slope
            inside = (slope > 0.0) & (newton >= low) & (newton <= high)
            step = np.where(inside, newton, 0.5 * (low + high))
            done = np.abs(step - s) <= 4.0 * np.finfo(np.float64).eps * s
            s = step
            if np.all(done | (residual == 0.0)):
                break
        return s


def polynomial_forward(
    V: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams, order: int = DEFAULT_ORDER
) -> FloatArray:
    """Return z of the series model truncated at ``order`` (even power of V) [m]."""
    shape = broadcast_shape(params, V, T)
    return PolynomialModel(order).forward_at(laws_at(T, params, shape), V)


def polynomial_slope(
    V: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams, order: int = DEFAULT_ORDER
) -> FloatArray:
    """Return dz/dV of the series model [m/V]."""
    shape = broadcast_shape(params, V, T)
    return PolynomialModel(order).slope_at(laws_at(T, params, shape), V)


def polynomial_inverse(
    z: npt.ArrayLike,
    T: npt.ArrayLike,
    params: ActuatorParams,
    v_limit: float = DEFAULT_V_LIMIT,
    order: int = DEFAULT_ORDER,
) -> InverseResult:
    """Return the voltage of the series model for set point ``z`` with its status."""
    shape = broadcast_shape(params, z, T)
    z = np.broadcast_to(np.asarray(z, np.float64), shape)
    return PolynomialModel(order).inverse_at(laws_at(T, params, shape), z, v_limit)
