"""The calibration's composite forward model: hyperbolic law plus the candidate effects.

One evaluation predicts the displacement of a block of actuators at a set of samples together
with its Jacobians: per-actuator ("local") law coefficients and effect parameters shared by
all actuators ("global"). Effects follow docs/architecture.md, "Effects beyond the basic
model"; every symbol below is that table's:

- ``sensor_lag``: T_a = T + tau dT/dt (the actuator leads the sensor by a first-order lag);
- ``delay``: V(t - d), applied when the inputs are built (see ``FitInputs``);
- ``hysteresis``: V_eff = (1 - a(T_a)) V + a(T_a) play_r(V),
  a(T_a) = weight exp(-(T_a - T_mean) / 4 degC); play_r is applied when the inputs are built;
- ``coupling``: z = z_free + c lap(z_free), 4-neighbour Laplacian, edges use only existing
  neighbours;
- ``thermal_expansion``: z += alpha (T_a - T_ref), fitted as alpha (T_a - T_mean) + offset;
- ``drift``: M_eff = M (1 - f (1 - exp(-(t / tau)^nu))), t from the start of the data;
- ``temperature_curvature``: quadratic T* terms m3, k3 in M(T*) and k(T*).

Local coefficients are ``[m2, m1, k2, k1]`` (+ ``[m3, k3]`` with curvature); L and Tm are fixed
(they are not separately identifiable from displacement data). The coupling Jacobian keeps only
each actuator's own law coefficients (neighbours' cross terms are of order c and dropped), which
still converges to the least-squares fit for the small coefficients a face sheet produces.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from es_physics.params import ActuatorParams

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: Canonical effect names, in the order candidates are listed.
CANDIDATES: Final = (
    "sensor_lag",
    "delay",
    "hysteresis",
    "coupling",
    "thermal_expansion",
    "drift",
    "temperature_curvature",
)
#: Temperature scale of the hysteresis weight's growth towards Tm [degC] (plant definition).
HYSTERESIS_TEMPERATURE_SCALE: Final = 4.0
#: The drift exponent nu is kept within exp(+-DRIFT_LOG_NU_LIMIT).
DRIFT_LOG_NU_LIMIT: Final = float(np.log(5.0))

#: Global (shared) parameters each effect adds to the Gauss-Newton problem, in order.
GLOBAL_PARAMETERS: Final[dict[str, tuple[str, ...]]] = {
    "sensor_lag": ("tau_s",),
    "delay": (),
    "hysteresis": ("weight",),
    "coupling": ("coefficient",),
    "thermal_expansion": ("alpha_m_per_degc", "offset_m"),
    "drift": ("fraction", "log_tau_s", "log_nu"),
    "temperature_curvature": (),
}
LINEAR_LAW: Final = ("m2", "m1", "k2", "k1")
QUADRATIC_LAW: Final = ("m2", "m1", "k2", "k1", "m3", "k3")


@dataclass(frozen=True)
class FitInputs:
    """Measured data of a block of A actuators at n samples, ready for the model.

    Attributes:
        t: seconds since the start of the data, shape (n,).
        voltage: command in effect at each sample (after any delay), shape (A, n) [V].
        play: play operator of the (delayed) command, shape (A, n) [V], or None.
        temperature: measured temperature, shape (A, n) [degC].
        temperature_rate: its time derivative, shape (A, n) [degC/s].
        displacement: measured displacement, shape (A, n) [m].
        valid: samples that enter the cost, shape (A, n).
        grid: (rows, cols) of the block (row-major), used by the coupling Laplacian.
        mean_temperature: mean temperature of the whole data set [degC].

    """

    t: FloatArray
    voltage: FloatArray
    play: FloatArray | None
    temperature: FloatArray
    temperature_rate: FloatArray
    displacement: FloatArray
    valid: BoolArray
    grid: tuple[int, int]
    mean_temperature: float


@dataclass(frozen=True)
class Evaluation:
    """Model prediction and Jacobians: (A, n), (A, n, P) and (A, n, G)."""

    prediction: FloatArray
    jac_local: FloatArray
    jac_global: FloatArray


def neighbour_laplacian(values: FloatArray, grid: tuple[int, int]) -> FloatArray:
    """Return the 4-neighbour Laplacian sum_j (x_j - x_i) of (A, n) values on a row-major grid."""
    rows, cols = grid
    x = values.reshape(rows, cols, -1)
    total = np.zeros_like(x)
    count = np.zeros((rows, cols, 1))
    total[1:] += x[:-1]
    total[:-1] += x[1:]
    total[:, 1:] += x[:, :-1]
    total[:, :-1] += x[:, 1:]
    count[1:] += 1.0
    count[:-1] += 1.0
    count[:, 1:] += 1.0
    count[:, :-1] += 1.0
    return np.asarray((total - count * x).reshape(values.shape), np.float64)


def neighbour_count(grid: tuple[int, int]) -> FloatArray:
    """Return the number of existing 4-neighbours of each actuator, shape (A, 1)."""
    rows, cols = grid
    ones = np.ones((rows * cols, 1))
    return -neighbour_laplacian(ones, grid)


class CompositeModel:
    """Hyperbolic law with a set of effects switched on; see the module docstring."""

    def __init__(self, effects: Sequence[str], base: ActuatorParams | None = None) -> None:
        """Build the model for ``effects`` (canonical names); L and Tm come from ``base``."""
        unknown = set(effects) - set(CANDIDATES)
        if unknown:
            raise ValueError(f"unknown effects: {sorted(unknown)}")
        self.effects: tuple[str, ...] = tuple(effects)
        base = base or ActuatorParams()
        self.L = float(np.asarray(base.L).ravel()[0])
        self.Tm = float(np.asarray(base.Tm).ravel()[0])
        self.local_names = QUADRATIC_LAW if "temperature_curvature" in self.effects else LINEAR_LAW
        self.global_names: tuple[str, ...] = tuple(
            f"{name}.{p}" for name in self.effects for p in GLOBAL_PARAMETERS[name]
        )

    def has(self, effect: str) -> bool:
        """Return whether ``effect`` is switched on."""
        return effect in self.effects

    def _global(self, g: FloatArray, name: str) -> float:
        return float(g[self.global_names.index(name)])

    def evaluate(
        self, local: FloatArray, g: FloatArray, data: FitInputs, jacobian: bool = True
    ) -> Evaluation:
        """Return the prediction and Jacobians for local (A, P) and global (G,) parameters.

        With ``jacobian=False`` only the prediction is computed (the Jacobians are empty).
        """
        names = self.global_names
        jac_g: dict[str, FloatArray] = {}
        T = data.temperature
        tau = self._global(g, "sensor_lag.tau_s") if self.has("sensor_lag") else 0.0
        Ta = T + tau * data.temperature_rate if tau else T

        V = data.voltage
        dV_dTa: FloatArray | None = None
        if self.has("hysteresis"):
            if data.play is None:
                raise ValueError("hysteresis needs the play operator in the inputs")
            weight = self._global(g, "hysteresis.weight")
            a_T = np.exp(-(Ta - data.mean_temperature) / HYSTERESIS_TEMPERATURE_SCALE)
            gap = data.play - V
            V = V + weight * a_T * gap
            dV_dweight = a_T * gap
            dV_dTa = -weight * a_T * gap / HYSTERESIS_TEMPERATURE_SCALE

        Ts = Ta - self.Tm
        m2, m1, k2, k1 = (local[:, i : i + 1] for i in range(4))
        curved = len(self.local_names) == 6
        m3 = local[:, 4:5] if curved else 0.0
        k3 = local[:, 5:6] if curved else 0.0
        M = m2 + Ts * (m1 + Ts * m3)
        k = k2 + Ts * (k1 + Ts * k3)
        th = np.tanh(k * V / self.L)
        dH_dM = self.L / (k * k) * th * th
        H = M * dH_dM
        columns: list[FloatArray] = []
        dH_dT: FloatArray | float = 0.0
        if jacobian:
            # th (1 - th^2) M / k: shared by the slope dz/dV and dz/dk
            slope_part = M * th * (1.0 - th * th) / k
            dH_dk = (V * slope_part - H) * (2.0 / k)
            dH_dV = 2.0 * slope_part
            columns = [dH_dM, dH_dM * Ts, dH_dk, dH_dk * Ts]
            if curved:
                columns += [dH_dM * Ts * Ts, dH_dk * Ts * Ts]
            if self.has("sensor_lag"):
                dH_dT = dH_dM * (m1 + 2.0 * m3 * Ts) + dH_dk * (k1 + 2.0 * k3 * Ts)
                if dV_dTa is not None:
                    dH_dT = dH_dT + dH_dV * dV_dTa

        scale: FloatArray | float = 1.0  # d(prediction)/dH
        if self.has("hysteresis") and jacobian:
            jac_g["hysteresis.weight"] = dH_dV * dV_dweight
        F = H
        if self.has("drift"):
            frac = self._global(g, "drift.fraction")
            d_tau = float(np.exp(self._global(g, "drift.log_tau_s")))
            # nu beyond [1/5, 5] makes a step or a flat line, not an aging law
            nu = float(
                np.exp(
                    np.clip(
                        self._global(g, "drift.log_nu"), -DRIFT_LOG_NU_LIMIT, DRIFT_LOG_NU_LIMIT
                    )
                )
            )
            ratio = np.maximum(data.t, 0.0) / d_tau
            s = np.minimum(ratio, 1e6) ** nu
            e = np.exp(-s)
            gain = 1.0 - frac * (1.0 - e)
            log_ratio = np.log(np.where(ratio > 0.0, ratio, 1.0))
            F = H * gain
            if jacobian:
                jac_g["drift.fraction"] = -(1.0 - e) * H
                jac_g["drift.log_tau_s"] = frac * e * nu * s * H
                jac_g["drift.log_nu"] = -frac * e * s * log_ratio * nu * H
                if "hysteresis.weight" in jac_g:
                    jac_g["hysteresis.weight"] = jac_g["hysteresis.weight"] * gain
            scale = gain
        # d F / d T_a, for the sensor lag (before the coupling spreads it to the neighbours)
        if self.has("sensor_lag") and jacobian:
            jac_g["sensor_lag.tau_s"] = scale * dH_dT * data.temperature_rate
        Z = F
        if self.has("coupling"):
            c = self._global(g, "coupling.coefficient")
            lap_F = neighbour_laplacian(F, data.grid)
            Z = F + c * lap_F
            # shared parameters move every actuator: (I + c lap) of their columns is exact
            for key, column in jac_g.items():
                jac_g[key] = column + c * neighbour_laplacian(column, data.grid)
            jac_g["coupling.coefficient"] = lap_F
            scale = scale * (1.0 - c * neighbour_count(data.grid))
        if self.has("thermal_expansion"):
            alpha = self._global(g, "thermal_expansion.alpha_m_per_degc")
            offset = self._global(g, "thermal_expansion.offset_m")
            Z = Z + alpha * (Ta - data.mean_temperature) + offset
            jac_g["thermal_expansion.alpha_m_per_degc"] = Ta - data.mean_temperature
            jac_g["thermal_expansion.offset_m"] = np.ones(1)
            if self.has("sensor_lag") and jacobian:
                jac_g["sensor_lag.tau_s"] = (
                    jac_g["sensor_lag.tau_s"] + alpha * data.temperature_rate
                )
        A, n = Z.shape
        if not jacobian:
            return Evaluation(np.asarray(Z, np.float64), np.zeros((A, n, 0)), np.zeros((A, n, 0)))
        jac_l = np.empty((A, n, len(columns)))
        for i, col in enumerate(columns):
            np.multiply(col, scale, out=jac_l[..., i])
        jac_glob = np.empty((A, n, len(names)))
        for i, name in enumerate(names):
            jac_glob[..., i] = jac_g[name]
        return Evaluation(np.asarray(Z, np.float64), jac_l, jac_glob)


def play_operator(
    command: FloatArray, threshold: float | FloatArray, keep: npt.NDArray[np.intp]
) -> FloatArray:
    """Return the backlash (play) operator of a command sequence at the rows ``keep``.

    ``command`` is (N, A), time-major; ``threshold`` a scalar or an array broadcasting against
    (A,) (a stack of thresholds works with ``command`` (N, 1)). The state starts at the clipped
    zero, y_0 = clip(0, V_0 - r, V_0 + r). Only the rows ``keep`` (sorted) are returned, so a
    long run needs no full-size output; the loop is over time, vectorised over actuators.
    """
    r = np.asarray(threshold, np.float64)
    shape = np.broadcast_shapes(command.shape[1:], r.shape)
    state = np.clip(np.zeros(shape), command[0] - r, command[0] + r)
    low = np.empty(shape)
    out = np.empty((len(keep), *shape))
    if not len(keep):
        return out
    # which output slot each needed row fills (rows may repeat)
    last = int(keep[-1])
    first_slot = np.searchsorted(keep, np.arange(last + 1), side="left")
    end_slot = np.searchsorted(keep, np.arange(last + 1), side="right")
    maximum, minimum, subtract, add = np.maximum, np.minimum, np.subtract, np.add
    for i in range(last + 1):
        row = command[i]
        subtract(row, r, out=low)
        maximum(state, low, out=state)
        add(row, r, out=low)
        minimum(state, low, out=state)
        if end_slot[i] > first_slot[i]:
            out[first_slot[i] : end_slot[i]] = state
    return out
