"""Mirror heating: absorbed UV power per cell and the face sheet -> actuator -> base network.

Network (per actuator cell, R x C grid, two nodes per cell)::

    P (UV, W) -> [face sheet T_f, C_f] --G_fa-- [actuator T_a, C_a] --G_ab-- base plate T_b
                     |  G_ff to the 4 neighbours     |  G_aa to the 4 neighbours
                                                    + Q (self-heating, W)

    C_f dT_f/dt = -G_fa (T_f - T_a) + G_ff lap(T_f) + P
    C_a dT_a/dt =  G_fa (T_f - T_a) - G_ab (T_a - T_b) + G_aa lap(T_a) + Q

lap is the 4-neighbour graph Laplacian with only existing neighbours at the border (an
insulated rim), T_b the base-plate temperature held by the thermal control (uniform, may
follow a profile). The face sheet radiates little to its vacuum surroundings; that path is
left out.

Exact integration: with thermal parameters uniform over the grid, the orthonormal 2-D DCT-II
diagonalises lap (eigenvalues (2 - 2 cos(pi i / R)) + (2 - 2 cos(pi j / C))), so the network
splits into R*C independent 2 x 2 systems. Their zero-order-hold discretisation over the step
dt (matrix exponential of the 5 x 5 augmented matrix) is computed once; a step transforms
the inputs (DCT as two small dense matrix products, D_R X D_C^T), multiplies each mode's 2 x 2
matrix and transforms back: O(N (R + C)) and exact for inputs held over dt.

Default values (a 5 mm pitch grid behind a 4 mm glass face sheet, PMN-PT actuator columns;
their one definition and derivation: :mod:`es_physics.thermal_network`, shared with the
estimator). Resulting time constants (:meth:`ThermalNetwork.time_constants`, 12 x 12 grid):
131 s for the uniform mode (the whole face sheet through the columns) down to 3.7 s
(actuator-local, high-order lateral modes): seconds to minutes, as in a real mirror. 10 mW
held in every cell
heats the actuators by 10e-3 / 3.4e-3 = 2.9 degC and the face sheet by 5.9 degC at steady
state. Every value is a parameter; scenarios shorten time by scaling the capacitances
(``ThermalParams.time_scaled``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, Final

import numpy as np
import scipy.linalg

from es_common.arrays import FloatArray
from es_physics.thermal_network import CellThermalParams
from es_sim_plant.errors import ScenarioError

PATTERNS: Final = ("uniform", "dipole", "quadrupole", "off_axis_spot", "annular")


@dataclass(frozen=True)
class ThermalParams(CellThermalParams):
    """The simulator's thermal parameters: the shared fields and defaults, a scenario's checks."""

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> ThermalParams:
        """Build from a scenario's ``thermal`` mapping; raise ``ScenarioError`` on bad entries.

        Raises:
            ScenarioError: bad keys, types or values (the message says which).

        """
        data = data or {}
        known = {f.name for f in fields(cls)}
        bad = set(data) - known
        if bad:
            raise ScenarioError(f"thermal: unknown key(s) {sorted(bad)}; known {sorted(known)}")
        try:
            params = cls(**{k: float(v) for k, v in data.items()})
        except (TypeError, ValueError):
            raise ScenarioError("thermal: every value must be a number") from None
        params.validate()
        return params

    def validate(self) -> None:
        """Raise ``ScenarioError`` unless capacitances and series conductances are > 0."""
        for name in ("face_capacitance", "actuator_capacitance", "face_to_actuator"):
            if not getattr(self, name) > 0.0:
                raise ScenarioError(f"thermal.{name} must be > 0")
        if not self.actuator_to_base > 0.0:
            raise ScenarioError(
                "thermal.actuator_to_base must be > 0 (the base plate sinks the heat)"
            )
        for name in ("face_lateral", "actuator_lateral"):
            if not getattr(self, name) >= 0.0:
                raise ScenarioError(f"thermal.{name} must be >= 0")

    def time_scaled(self, time_scale: float) -> ThermalParams:
        """Return a copy whose capacitances (hence every time constant) scale by ``time_scale``."""
        return replace(
            self,
            face_capacitance=self.face_capacitance * time_scale,
            actuator_capacitance=self.actuator_capacitance * time_scale,
        )


def laplacian_eigenvalues(shape: tuple[int, int]) -> FloatArray:
    """Return the eigenvalues (>= 0) of minus the grid graph Laplacian, indexed by DCT mode."""
    rows, cols = shape
    lam_r = 2.0 - 2.0 * np.cos(np.pi * np.arange(rows) / rows)
    lam_c = 2.0 - 2.0 * np.cos(np.pi * np.arange(cols) / cols)
    return np.asarray(lam_r[:, None] + lam_c[None, :], np.float64)


def dct_matrix(n: int) -> FloatArray:
    """Return the orthonormal DCT-II matrix D (n x n): x_hat = D x, x = D.T x_hat.

    Its rows are the eigenvectors of the path graph's Laplacian (insulated ends).
    """
    k = np.arange(n)[:, None]
    m = np.arange(n)[None, :]
    d = np.sqrt(2.0 / n) * np.cos(np.pi * k * (2 * m + 1) / (2 * n))
    d[0] /= np.sqrt(2.0)
    return np.asarray(d, np.float64)


class ThermalNetwork:
    """The discretised network of one grid, stepped exactly with inputs held over ``dt``.

    State: face-sheet and actuator temperatures [degC], each (R, C). Inputs per step: absorbed
    UV power P (R, C) [W] into the face sheet, actuator heat Q (R, C) [W], base temperature
    T_b [degC] (scalar).
    """

    def __init__(
        self,
        shape: tuple[int, int],
        params: ThermalParams,
        dt: float,
        initial_temperature: float,
    ) -> None:
        """Build the network for the grid, stepping ``dt`` [s] from ``initial_temperature`` [degC].

        Raises:
            ScenarioError: bad keys, types or values (the message says which).

        """
        if dt <= 0.0:
            raise ScenarioError("thermal step dt must be > 0")
        params.validate()
        self.shape = shape
        self.params = params
        self.dt = dt
        lam = laplacian_eigenvalues(shape)
        p = params
        # Continuous 2 x 2 modal dynamics and 2 x 3 input matrices (P, Q, T_b) per mode.
        a_ff = -(p.face_to_actuator + p.face_lateral * lam) / p.face_capacitance
        a_fa = np.full_like(lam, p.face_to_actuator / p.face_capacitance)
        a_af = np.full_like(lam, p.face_to_actuator / p.actuator_capacitance)
        a_aa = (
            -(p.face_to_actuator + p.actuator_to_base + p.actuator_lateral * lam)
            / p.actuator_capacitance
        )
        aug = np.zeros((*shape, 5, 5))
        aug[..., 0, 0], aug[..., 0, 1], aug[..., 1, 0], aug[..., 1, 1] = a_ff, a_fa, a_af, a_aa
        aug[..., 0, 2] = 1.0 / p.face_capacitance
        aug[..., 1, 3] = 1.0 / p.actuator_capacitance
        aug[..., 1, 4] = p.actuator_to_base / p.actuator_capacitance
        self._continuous = aug[..., :2, :].copy()
        # A mode's matrix depends on its eigenvalue only, and lam[i, j] == lam[j, i] on a
        # square grid: the exponential of each distinct matrix is computed once (scipy's
        # expm treats every matrix of a stack on its own, so the values are the same).
        distinct, index = np.unique(lam, return_inverse=True)
        index = index.ravel()
        one_of_each = np.zeros(distinct.size, np.intp)
        one_of_each[index] = np.arange(lam.size)  # any mode of each eigenvalue will do
        disc = scipy.linalg.expm(aug.reshape(-1, 5, 5)[one_of_each] * dt)[index]
        disc = disc.reshape(*shape, 5, 5)
        # Each coefficient of the modal update as its own contiguous (R, C) array: the
        # elementwise products of a step then run on contiguous memory, not 4-strided views.
        self._a00, self._a01, self._a10, self._a11 = (
            np.ascontiguousarray(disc[..., i, j]) for i, j in ((0, 0), (0, 1), (1, 0), (1, 1)))
        self._b_face_p, self._b_act_p, self._b_face_q, self._b_act_q = (
            np.ascontiguousarray(disc[..., i, j]) for i, j in ((0, 2), (1, 2), (0, 3), (1, 3)))
        self._b_face_base, self._b_act_base = float(disc[0, 0, 0, 4]), float(disc[0, 0, 1, 4])
        self._sqrt_n = float(np.sqrt(shape[0] * shape[1]))
        # Small dense DCT matrices beat an FFT call at these sizes (no per-call overhead);
        # both orientations contiguous, so that every product is a plain GEMM.
        self._d_rows = dct_matrix(shape[0])
        self._d_rows_t = np.ascontiguousarray(self._d_rows.T)
        self._d_cols = dct_matrix(shape[1])
        self._d_cols_t = np.ascontiguousarray(self._d_cols.T)
        # Modal state (2, R, C): face sheet and actuator.
        self._modal = np.zeros((2, *shape))
        self.set_uniform(initial_temperature)

    def set_uniform(self, temperature: float) -> None:
        """Put both layers at one uniform temperature (equilibrium with no heat input)."""
        self._modal[:] = 0.0
        self._modal[:, 0, 0] = temperature * self._sqrt_n
        self._layers: list[FloatArray | None] = [None, None]

    def _dct(self, x: FloatArray) -> FloatArray:
        return np.asarray(self._d_rows @ x @ self._d_cols_t, np.float64)

    def _idct(self, x: FloatArray) -> FloatArray:
        return np.asarray(self._d_rows_t @ x @ self._d_cols, np.float64)

    def step(self, power: FloatArray, actuator_heat: FloatArray | None, base: float) -> None:
        """Advance one ``dt`` with P, Q and T_b held over the step."""
        p_hat = self._dct(power)
        x = self._modal
        f = self._a00 * x[0] + self._a01 * x[1] + self._b_face_p * p_hat
        a = self._a10 * x[0] + self._a11 * x[1] + self._b_act_p * p_hat
        if actuator_heat is not None:
            q_hat = self._dct(actuator_heat)
            f += self._b_face_q * q_hat
            a += self._b_act_q * q_hat
        # T_b is uniform: only the (0, 0) mode sees it.
        tb_hat = base * self._sqrt_n
        f[0, 0] += self._b_face_base * tb_hat
        a[0, 0] += self._b_act_base * tb_hat
        x[0], x[1] = f, a
        self._layers = [None, None]

    def _layer(self, index: int) -> FloatArray:
        """Return one layer's temperatures [degC] (R, C), transformed back once per step."""
        layer = self._layers[index]
        if layer is None:
            layer = self._idct(self._modal[index])
            layer.flags.writeable = False
            self._layers[index] = layer
        return layer

    def actuator_temperatures(self) -> FloatArray:
        """Return the actuator temperatures [degC], (R, C) (read-only)."""
        return self._layer(1)

    def temperatures(self) -> tuple[FloatArray, FloatArray]:
        """Return (face-sheet, actuator) temperatures [degC], each (R, C) (read-only)."""
        return self._layer(0), self._layer(1)

    def steady_state(
        self, power: FloatArray, actuator_heat: FloatArray | None, base: float
    ) -> tuple[FloatArray, FloatArray]:
        """Return the (face, actuator) equilibrium for constant inputs (solved per mode)."""
        c = self._continuous
        p_hat = self._dct(np.asarray(power, np.float64))
        q_hat = self._dct(np.zeros(self.shape) if actuator_heat is None else actuator_heat)
        tb_hat = np.zeros(self.shape)
        tb_hat[0, 0] = base * self._sqrt_n
        rhs = -(
            c[..., :, 2] * p_hat[..., None]
            + c[..., :, 3] * q_hat[..., None]
            + c[..., :, 4] * tb_hat[..., None]
        )
        x = np.asarray(np.linalg.solve(c[..., :, :2], rhs[..., None])[..., 0], np.float64)
        both = self._idct(np.moveaxis(x, -1, 0))
        return both[0], both[1]

    def time_constants(self) -> FloatArray:
        """Return the network's time constants [s], sorted descending (2 R C values)."""
        eig = np.linalg.eigvals(self._continuous[..., :, :2])
        return np.sort(-1.0 / eig.real.ravel())[::-1]


@dataclass(frozen=True)
class Illumination:
    """Spatial distribution of the absorbed UV power over the grid.

    Coordinates are normalised: x across columns and y across rows, each in [-1, 1] over the
    grid. Poles are Gaussian spots of width ``sigma`` at distance ``offset`` from the centre:
    dipole on the axis rotated by ``angle_deg``, quadrupole on both diagonals (rotated),
    annular a ring of radius ``offset``, off_axis_spot one pole at (``spot_x``, ``spot_y``).
    ``background`` is the fraction spread uniformly (scattered light). The map is normalised
    so that it sums to ``total_power_w`` [W absorbed by the whole mirror while exposing].
    """

    pattern: str = "uniform"
    total_power_w: float = 1.0
    offset: float = 0.6
    sigma: float = 0.25
    angle_deg: float = 0.0
    spot_x: float = 0.5
    spot_y: float = 0.3
    background: float = 0.1

    def validate(self) -> None:
        """Raise ``ScenarioError`` on an unknown pattern or out-of-range parameter."""
        if self.pattern not in PATTERNS:
            raise ScenarioError(f"illumination.pattern {self.pattern!r} is not one of {PATTERNS}")
        if self.total_power_w < 0.0:
            raise ScenarioError("illumination.total_power_w must be >= 0")
        if self.sigma <= 0.0:
            raise ScenarioError("illumination.sigma must be > 0")
        if not 0.0 <= self.background <= 1.0:
            raise ScenarioError("illumination.background must be in [0, 1]")

    def power_map(self, shape: tuple[int, int]) -> FloatArray:
        """Return the absorbed power per cell [W] while exposing, shape ``shape``."""
        y, x = normalised_coordinates(shape)
        angle = np.deg2rad(self.angle_deg)
        centres: list[tuple[float, float]]
        if self.pattern == "dipole":
            centres = [(self.offset, 0.0), (-self.offset, 0.0)]
        elif self.pattern == "quadrupole":
            d = self.offset / np.sqrt(2.0)
            centres = [(d, d), (-d, d), (-d, -d), (d, -d)]
        elif self.pattern == "off_axis_spot":
            centres = [(self.spot_x, self.spot_y)]
            angle = 0.0
        else:
            centres = []
        shape_map = np.zeros(shape)
        for cx, cy in centres:
            rx = cx * np.cos(angle) - cy * np.sin(angle)
            ry = cx * np.sin(angle) + cy * np.cos(angle)
            shape_map += np.exp(-((x - rx) ** 2 + (y - ry) ** 2) / (2.0 * self.sigma**2))
        if self.pattern == "annular":
            r = np.hypot(x, y)
            shape_map = np.exp(-((r - self.offset) ** 2) / (2.0 * self.sigma**2))
        if self.pattern == "uniform" or shape_map.sum() <= 0.0:
            shape_map = np.ones(shape)
        shaped = shape_map / shape_map.sum()
        uniform = np.full(shape, 1.0 / (shape[0] * shape[1]))
        mix = self.background if self.pattern != "uniform" else 1.0
        return np.asarray(self.total_power_w * ((1.0 - mix) * shaped + mix * uniform), np.float64)


def normalised_coordinates(shape: tuple[int, int]) -> tuple[FloatArray, FloatArray]:
    """Return (y, x) grids in [-1, 1] (0 for a single row or column), shape ``shape``."""
    rows, cols = shape
    y = np.linspace(-1.0, 1.0, rows) if rows > 1 else np.zeros(1)
    x = np.linspace(-1.0, 1.0, cols) if cols > 1 else np.zeros(1)
    yy, xx = np.meshgrid(y, x, indexing="ij")
    return yy, xx


@dataclass(frozen=True)
class ExposureSchedule:
    """Exposures of ``exposure_s`` separated by wafer swaps of ``swap_s`` (light off).

    The first exposure starts at ``start_s``; ``count`` exposures (0: repeat to the end).
    """

    start_s: float = 0.0
    exposure_s: float = 20.0
    swap_s: float = 8.0
    count: int = 0

    def validate(self) -> None:
        """Raise ``ScenarioError`` on negative times or a non-positive exposure."""
        if self.exposure_s <= 0.0 or self.swap_s < 0.0 or self.start_s < 0.0 or self.count < 0:
            raise ScenarioError(
                "exposure schedule: exposure_s > 0, swap_s >= 0, start_s >= 0, count >= 0"
            )

    def time_scaled(self, time_scale: float) -> ExposureSchedule:
        """Return a copy with every time multiplied by ``time_scale``."""
        return replace(
            self,
            start_s=self.start_s * time_scale,
            exposure_s=self.exposure_s * time_scale,
            swap_s=self.swap_s * time_scale,
        )

    def _exposed_until(self, t: float) -> float:
        """Total exposed time in [0, t]."""
        if t <= self.start_s:
            return 0.0
        period = self.exposure_s + self.swap_s
        elapsed = t - self.start_s
        full = math.floor(elapsed / period)  # scalar: math is ~10x cheaper than numpy
        if self.count and full >= self.count:
            return self.count * self.exposure_s
        return float(full * self.exposure_s + min(elapsed - full * period, self.exposure_s))

    def on_fraction(self, t0: float, t1: float) -> float:
        """Return the fraction of [t0, t1) with the light on (exact for a held step)."""
        return (self._exposed_until(t1) - self._exposed_until(t0)) / (t1 - t0)


@dataclass(frozen=True)
class BaseProfile:
    """Base-plate (thermal control) temperature vs time: points (t [s], T [degC]).

    ``interpolation``: "linear" (ramps) or "step" (hold each value until the next point).
    Before the first point and after the last the end values hold.
    """

    times: tuple[float, ...] = (0.0,)
    temperatures: tuple[float, ...] = (42.0,)
    interpolation: str = "linear"

    def validate(self) -> None:
        """Raise ``ScenarioError`` on unsorted or mismatched points or unknown interpolation."""
        if len(self.times) != len(self.temperatures) or not self.times:
            raise ScenarioError(
                "base_temperature: times and temperatures need the same length >= 1"
            )
        if any(b < a for a, b in zip(self.times, self.times[1:], strict=False)):
            raise ScenarioError("base_temperature: times must be non-decreasing")
        if self.interpolation not in ("linear", "step"):
            raise ScenarioError("base_temperature.interpolation must be 'linear' or 'step'")
        if not all(np.isfinite(self.temperatures)):
            raise ScenarioError("base_temperature: temperatures must be finite")

    def time_scaled(self, time_scale: float) -> BaseProfile:
        """Return a copy with every time multiplied by ``time_scale``."""
        return replace(self, times=tuple(t * time_scale for t in self.times))

    def at(self, t: float) -> float:
        """Return T_b at time ``t``."""
        if self.interpolation == "step":
            index = int(np.searchsorted(self.times, t, side="right")) - 1
            return float(self.temperatures[max(index, 0)])
        return float(np.interp(t, self.times, self.temperatures))

    def mean(self, t0: float, t1: float) -> float:
        """Return the mean of T_b over [t0, t1] (exact for linear and step profiles)."""
        if len(self.times) == 1:
            return float(self.temperatures[0])
        if self.interpolation == "step":
            return self.at(t0) if self.at(t1) == self.at(t0) else self._integral(t0, t1) / (t1 - t0)
        return self._integral(t0, t1) / (t1 - t0)

    def _integral(self, t0: float, t1: float) -> float:
        knots = [t for t in self.times if t0 < t < t1]
        points = np.array([t0, *knots, t1])
        if self.interpolation == "linear":
            values = np.interp(points, self.times, self.temperatures)
            return float(np.sum(0.5 * (values[1:] + values[:-1]) * np.diff(points)))
        values = np.array([self.at(t) for t in points[:-1]])
        return float(np.sum(values * np.diff(points)))
