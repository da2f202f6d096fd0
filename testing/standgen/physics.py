"""The actuator law of the test stand, written from ../shared/docs/physics.md alone.

A second implementation of the physics (nothing is imported from es_sim_plant, es_feedforward
or es_thermal), so that a mistake shared by the project's plant and its calibration cannot hide.

Hyperbolic (Hom-Shankar) law per actuator, SI units, temperatures in degC::

    z = (M L / k^2) tanh^2(k V / L),   M(T*) = m1 T* + m2 + m3 T*^2,
    k(T*) = k1 T* + k2 + k3 T*^2,       T* = T - Tm.

Reference values (physics.md): Tm = 38 degC, L = 0.2 mm, m1 = -41.5e-18 m^2/V^2/degC,
m2 = 1504e-18 m^2/V^2, k1 = -17.375e-9 m/V/degC, k2 = 1167.5e-9 m/V; at 40 degC
d_max = 0.966 nm/V, V_max = 116 V, z_sat = 221 nm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from standgen._typing import FloatArray

#: Temperature of maximum permittivity [degC].
TM_DEGC: Final = 38.0
#: Actuator thickness [m].
THICKNESS_M: Final = 0.2e-3
#: u* = atanh(1 / sqrt(3)): where the slope dz/dV peaks.
U_STAR: Final = float(np.arctanh(1.0 / np.sqrt(3.0)))


@dataclass(frozen=True)
class Law:
    """Coefficients of the temperature laws; each a scalar or an (R, C) per-actuator map.

    Attributes:
        m1: [m^2/V^2/degC]; m2: [m^2/V^2]; m3: [m^2/V^2/degC^2].
        k1: [m/V/degC]; k2: [m/V]; k3: [m/V/degC^2].
        L: thickness [m]; Tm: temperature of maximum permittivity [degC].

    """

    m1: float | FloatArray = -41.5e-18
    m2: float | FloatArray = 1504e-18
    m3: float | FloatArray = 0.0
    k1: float | FloatArray = -17.375e-9
    k2: float | FloatArray = 1167.5e-9
    k3: float | FloatArray = 0.0
    L: float = THICKNESS_M
    Tm: float = TM_DEGC

    def M(self, T: npt.ArrayLike) -> FloatArray:
        """Electrostrictive coefficient M(T) [m^2/V^2] at temperature ``T`` [degC]."""
        ts = np.asarray(T, np.float64) - self.Tm
        return np.asarray(self.m1 * ts + self.m2 + self.m3 * ts * ts, np.float64)

    def k(self, T: npt.ArrayLike) -> FloatArray:
        """Relaxation coefficient k(T) [m/V] at temperature ``T`` [degC]."""
        ts = np.asarray(T, np.float64) - self.Tm
        return np.asarray(self.k1 * ts + self.k2 + self.k3 * ts * ts, np.float64)

    def displacement(self, V: npt.ArrayLike, T: npt.ArrayLike,
                     gain: npt.ArrayLike = 1.0) -> FloatArray:
        """Displacement z [m] for voltage ``V`` [V] at temperature ``T`` [degC].

        ``gain`` scales M (aging); arrays broadcast (e.g. (N, R, C) against (R, C) maps).
        Even in V: a negative voltage expands the actuator as much as a positive one.
        """
        M = self.M(T) * np.asarray(gain, np.float64)
        k = self.k(T)
        return np.asarray(M * self.L / k**2 * np.tanh(k * np.asarray(V) / self.L) ** 2,
                          np.float64)

    def z_sat(self, T: npt.ArrayLike) -> FloatArray:
        """Saturation displacement M L / k^2 [m]."""
        return np.asarray(self.M(T) * self.L / self.k(T) ** 2, np.float64)

    def d_max(self, T: npt.ArrayLike) -> FloatArray:
        """Largest slope dz/dV = 4 M / (3 sqrt(3) k) [m/V]."""
        return np.asarray(4.0 * self.M(T) / (3.0 * np.sqrt(3.0) * self.k(T)), np.float64)

    def v_max(self, T: npt.ArrayLike) -> FloatArray:
        """Voltage of the largest slope, u* L / k [V]."""
        return np.asarray(U_STAR * self.L / self.k(T), np.float64)
