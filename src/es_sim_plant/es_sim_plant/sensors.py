"""Temperature sensors on the actuator grid: placement, lag, offset, noise and quantisation.

A sensor sits at a (row, col) position on the grid; fractional positions read the bilinear
interpolation of the actuator temperatures of the four surrounding actuators (a sensor
between actuators). Without positions there is one sensor per actuator, sensor i on actuator
i in row-major order (the interface contract's S == R*C case).

Reading chain: site temperature -> first-order lag (effect ``sensor_lag``, tau; exact
discretisation per plant step) -> + fixed offset (per sensor, seeded) -> + white noise
(rms ``noise_sd``) -> quantisation to ``resolution``. Defaults follow the thesis's NTC chain:
0.08 degC peak variation at a set point -> noise 0.02 degC rms, 0.01 degC resolution;
offsets are 0 unless the scenario asks for a spread.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from es_common.arrays import FloatArray, IndexArray
from es_sim_plant.errors import ScenarioError


@dataclass(frozen=True)
class SensorConfig:
    """Sensor placement and imperfections.

    Attributes:
        positions: ``None`` (one per actuator) or (row, col) pairs, fractional allowed,
            within [0, R-1] x [0, C-1].
        noise_sd: white measurement noise, rms [degC].
        resolution: quantisation step [degC] (0: none).
        offset_sd: spread of the fixed per-sensor offsets [degC] (seeded).
        offsets: explicit offsets [degC], one per sensor (overrides ``offset_sd``).

    """

    positions: tuple[tuple[float, float], ...] | None = None
    noise_sd: float = 0.02
    resolution: float = 0.01
    offset_sd: float = 0.0
    offsets: tuple[float, ...] | None = None

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> SensorConfig:
        """Build from a scenario's ``sensors`` mapping; raise ``ScenarioError`` on bad entries.

        Raises:
            ScenarioError: bad keys, types or values (the message says which).

        """
        data = dict(data or {})
        known = {"positions", "noise_sd", "resolution", "offset_sd", "offsets"}
        bad = set(data) - known
        if bad:
            raise ScenarioError(f"sensors: unknown key(s) {sorted(bad)}; known {sorted(known)}")
        try:
            positions: list[list[float]] | None = data.get("positions")
            pos = (
                None if positions is None else tuple((float(p[0]), float(p[1])) for p in positions)
            )
            if positions is not None and any(len(p) != 2 for p in positions):
                raise ScenarioError
            offsets = data.get("offsets")
            config = cls(
                positions=pos,
                noise_sd=float(data.get("noise_sd", cls.noise_sd)),
                resolution=float(data.get("resolution", cls.resolution)),
                offset_sd=float(data.get("offset_sd", cls.offset_sd)),
                offsets=None if offsets is None else tuple(float(o) for o in offsets),
            )
        except (TypeError, ValueError, IndexError):
            raise ScenarioError(
                "sensors: positions must be [[row, col], ...], other values numbers"
            ) from None
        if config.noise_sd < 0.0 or config.resolution < 0.0 or config.offset_sd < 0.0:
            raise ScenarioError("sensors: noise_sd, resolution and offset_sd must be >= 0")
        return config


def flat_positions(values: list[float]) -> tuple[tuple[float, float], ...]:
    """Return (row, col) pairs from a flat [r0, c0, r1, c1, ...] list (node parameter form).

    Raises:
        ScenarioError: odd length.

    """
    if len(values) % 2:
        raise ScenarioError("sensor positions need an even count [r0, c0, r1, c1, ...]")
    return tuple((float(values[i]), float(values[i + 1])) for i in range(0, len(values), 2))


class SensorArray:
    """The sensors of one grid; call :meth:`track` every plant step and :meth:`read` to sample."""

    def __init__(
        self,
        shape: tuple[int, int],
        *,
        config: SensorConfig,
        lag_tau: float | None,
        dt: float,
        initial_temperature: float,
        rng_offsets: np.random.Generator,
        rng_noise: np.random.Generator,
    ) -> None:
        """Build the sensor array for the grid from ``config`` and the two random streams.

        Raises:
            ScenarioError: bad keys, types or values (the message says which).

        """
        rows, cols = shape
        self.config = config
        self._rng = rng_noise
        if config.positions is None:
            self._index: IndexArray | None = None
            self._weights: FloatArray | None = None
            self.count = rows * cols
        else:
            pos = np.asarray(config.positions, np.float64).reshape(-1, 2)
            if pos.size == 0:
                raise ScenarioError("sensors: at least one sensor position is needed")
            r, c = pos[:, 0], pos[:, 1]
            if (
                np.any(~np.isfinite(pos))
                or np.any(r < 0)
                or np.any(r > rows - 1)
                or np.any(c < 0)
                or np.any(c > cols - 1)
            ):
                raise ScenarioError(
                    f"sensor positions must lie within [0, {rows - 1}] x [0, {cols - 1}]"
                )
            r0 = np.minimum(np.floor(r).astype(np.intp), max(rows - 2, 0))
            c0 = np.minimum(np.floor(c).astype(np.intp), max(cols - 2, 0))
            r1 = np.minimum(r0 + 1, rows - 1)
            c1 = np.minimum(c0 + 1, cols - 1)
            fr, fc = r - r0, c - c0
            self._index = np.stack(
                [r0 * cols + c0, r0 * cols + c1, r1 * cols + c0, r1 * cols + c1], axis=1
            )
            self._weights = np.stack(
                [(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc], axis=1
            )
            self.count = len(pos)
        if config.offsets is not None:
            if len(config.offsets) != self.count:
                raise ScenarioError(
                    f"sensors.offsets has {len(config.offsets)} values for {self.count} sensors"
                )
            self.offsets = np.asarray(config.offsets, np.float64)
        else:
            self.offsets = config.offset_sd * rng_offsets.standard_normal(self.count)
        self._decay = 0.0 if lag_tau is None else float(np.exp(-dt / lag_tau))
        self._lagged = np.full(self.count, float(initial_temperature))

    def site_temperature(self, actuator_temperature: FloatArray) -> FloatArray:
        """Return the temperature at each sensor's site (S,) from the actuator grid (R, C)."""
        flat = actuator_temperature.reshape(-1)
        if self._index is None or self._weights is None:
            return flat.copy()
        return np.asarray(np.sum(flat[self._index] * self._weights, axis=1), np.float64)

    def track(self, actuator_temperature: FloatArray) -> None:
        """Advance the sensor lag by one plant step to the new actuator temperatures."""
        site = self.site_temperature(actuator_temperature)
        if self._decay == 0.0:
            self._lagged = site
        else:
            self._lagged = site + (self._lagged - site) * self._decay

    def read(self) -> FloatArray:
        """Return one noisy, quantised sample (S,) [degC] (draws from the noise stream)."""
        value = self._lagged + self.offsets
        if self.config.noise_sd > 0.0:
            value = value + self.config.noise_sd * self._rng.standard_normal(self.count)
        q = self.config.resolution
        if q > 0.0:
            value = np.round(value / q) * q
        return np.asarray(value, np.float64)
