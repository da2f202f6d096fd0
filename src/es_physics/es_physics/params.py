"""Electrostrictive actuator parameters and their temperature laws.

M(T) and k(T) are polynomials in T* = T - Tm (linear by default, quadratic when ``m3``/``k3``
are non-zero), with the thesis's defaults for 0.85PMN-0.15PT, L = 0.2 mm, Tm = 38 degC
(``shared/docs/physics.md``). Every field may be a scalar or an array that broadcasts against
the actuator grid, so one object describes one actuator or a whole grid with per-actuator maps.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Final

import numpy as np
import numpy.typing as npt

from es_common.arrays import FloatArray

ParamValue = float | FloatArray

#: 95 % confidence intervals of the thesis's linear fits (40-52 degC), SI units.
THESIS_INTERVALS_95: Final[dict[str, tuple[float, float]]] = {
    "m1": (-48e-18, -35e-18),
    "m2": (1170e-18, 1840e-18),
    "k1": (-20.7e-9, -15e-9),
    "k2": (1052.5e-9, 1322.5e-9),
}

#: Below Tm + 2 degC hysteresis and frequency dispersion set in: the laws do not hold there.
VALIDITY_MARGIN_BELOW_TM: Final = 2.0
#: Beyond Tm + 30 degC M(T) nears zero: the laws are not extrapolated there.
VALIDITY_SPAN_ABOVE_TM: Final = 30.0


@dataclass(frozen=True)
class ActuatorParams:
    """Model parameters of one actuator or, with array fields, of a grid of actuators.

    Attributes:
        L: actuator thickness [m].
        Tm: temperature of maximum permittivity [degC].
        m1, m2, m3: M(T*) = m2 + m1 T* + m3 T*^2 [m^2/V^2, per degC, per degC^2].
        k1, k2, k3: k(T*) = k2 + k1 T* + k3 T*^2 [m/V, per degC, per degC^2].

    """

    L: ParamValue = 0.2e-3
    Tm: ParamValue = 38.0
    m1: ParamValue = -41.5e-18
    m2: ParamValue = 1504e-18
    m3: ParamValue = 0.0
    k1: ParamValue = -17.375e-9
    k2: ParamValue = 1167.5e-9
    k3: ParamValue = 0.0

    @classmethod
    def thesis(cls) -> ActuatorParams:
        """Return the thesis's fitted parameters (linear laws)."""
        return cls()

    def as_arrays(self, shape: tuple[int, ...]) -> ActuatorParams:
        """Return a copy whose every field is a float64 array of ``shape`` (per-actuator maps)."""
        return replace(
            self,
            **{
                f.name: np.broadcast_to(np.asarray(getattr(self, f.name), np.float64), shape).copy()
                for f in fields(self)
            },
        )

    def select(self, index: int | tuple[int, ...] | slice) -> ActuatorParams:
        """Return the parameters of the actuators at ``index`` (scalar fields pass through)."""
        return replace(
            self,
            **{
                f.name: v[index] if isinstance(v := getattr(self, f.name), np.ndarray) else v
                for f in fields(self)
            },
        )

    def t_star(self, T: npt.ArrayLike) -> FloatArray:
        """Return T* = T - Tm."""
        return np.asarray(T, np.float64) - self.Tm

    def M(self, T: npt.ArrayLike) -> FloatArray:
        """Return the electrostrictive coefficient M(T) [m^2/V^2]."""
        ts = self.t_star(T)
        return np.asarray(self.m2 + ts * (self.m1 + ts * self.m3), np.float64)

    def k(self, T: npt.ArrayLike) -> FloatArray:
        """Return the relaxation coefficient k(T) [m/V]."""
        ts = self.t_star(T)
        return np.asarray(self.k2 + ts * (self.k1 + ts * self.k3), np.float64)

    def validity_range(self) -> tuple[ParamValue, ParamValue]:
        """Return the (low, high) temperatures [degC] in which the laws are trusted."""
        return self.Tm + VALIDITY_MARGIN_BELOW_TM, self.Tm + VALIDITY_SPAN_ABOVE_TM
