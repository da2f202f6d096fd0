"""The actuator grid: per-actuator hyperbolic model, manufacturing spread, amplifier, effects.

Each actuator follows z = (M L / k^2) tanh^2(k V / L) with M(T), k(T) from
:mod:`es_physics.params` / :mod:`es_physics.laws` (the same library the
feedforward inverts). The nominal parameters get a seeded relative spread per actuator
(manufacturing scatter; default 2 % on m2, 1 % on k2, so gains scatter by ~2 %).

Time: a plant step of ``dt`` is split into ``substeps`` internal steps (default 10: 1 kHz at
a 100 Hz control rate). The amplifier holds the command over the step and saturates at
``v_limit``; the transport delay is resolved to one internal step, so within a plant step the
applied voltage switches once, from the older to the newer delayed command, at a known
internal step. Hysteresis (a rate-independent play operator) therefore changes state at most
twice per step and is evaluated exactly; the frequency dispersion (a first-order relaxation)
filters its output at every internal step; the dielectric loss of that switch heats the
actuator (effect ``self_heating``). Displacements can be returned for every internal step
(a high-rate "interferometer") or only for the end of the step.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from es_physics.effects.coupling import grid_laplacian
from es_physics.effects.drift import drift_factor
from es_physics.effects.frequency_dispersion import (
    relaxation_advance,
    relaxation_decay,
    relaxation_output,
)
from es_physics.effects.hysteresis import (
    MAX_OPERATORS,
    hysteresis_weight,
    operator_names,
    play,
)
from es_physics.laws import DEFAULT_V_LIMIT, hyperbolic_forward
from es_physics.params import ActuatorParams
from es_sim_plant.effects import Effects
from es_sim_plant.errors import ScenarioError

FloatArray = npt.NDArray[np.float64]

#: Fields of ActuatorParams that may get a manufacturing spread.
SPREADABLE = tuple(f.name for f in fields(ActuatorParams))


@dataclass(frozen=True)
class ActuatorConfig:
    """Nominal parameters, spread, amplifier limit and internal rate of the grid.

    Attributes:
        params: nominal actuator parameters (scalars; thesis values by default).
        spread: relative standard deviation per parameter name, e.g. ``{"m2": 0.02}``.
        v_limit: amplifier output limit [V] (symmetric).
        substeps: internal integration steps per plant step (>= 1).

    """

    params: ActuatorParams = field(default_factory=ActuatorParams)
    spread: dict[str, float] = field(default_factory=lambda: {"m2": 0.02, "k2": 0.01})
    v_limit: float = DEFAULT_V_LIMIT
    substeps: int = 10

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> ActuatorConfig:
        """Build from a scenario's ``actuators`` mapping; raise ``ScenarioError`` on bad entries.

        Raises:
            ScenarioError: bad keys, types or values (the message says which).

        """
        data = dict(data or {})
        known = {"params", "spread", "v_limit", "substeps"}
        bad = set(data) - known
        if bad:
            raise ScenarioError(f"actuators: unknown key(s) {sorted(bad)}; known {sorted(known)}")
        raw_params = data.get("params") or {}
        raw_spread = data.get("spread", cls().spread) or {}
        for what, mapping in (("params", raw_params), ("spread", raw_spread)):
            if not isinstance(mapping, dict):
                raise ScenarioError(f"actuators.{what} must be a mapping")
            unknown = set(mapping) - set(SPREADABLE)
            if unknown:
                raise ScenarioError(f"actuators.{what}: unknown name(s) {sorted(unknown)}")
        try:
            config = cls(
                params=ActuatorParams(**{k: float(v) for k, v in raw_params.items()}),
                spread={k: float(v) for k, v in raw_spread.items()},
                v_limit=float(data.get("v_limit", DEFAULT_V_LIMIT)),
                substeps=int(data.get("substeps", cls.substeps)),
            )
        except (TypeError, ValueError):
            raise ScenarioError("actuators: values must be numbers") from None
        config.validate()
        return config

    def validate(self) -> None:
        """Raise ``ScenarioError`` on a non-positive limit or substep count or negative spread."""
        if not self.v_limit > 0.0:
            raise ScenarioError("actuators.v_limit must be > 0")
        if self.substeps < 1:
            raise ScenarioError("actuators.substeps must be >= 1")
        if any(not 0.0 <= s < 0.5 for s in self.spread.values()):
            raise ScenarioError("actuators.spread values must be in [0, 0.5)")


def spread_params(
    nominal: ActuatorParams,
    spread: dict[str, float],
    shape: tuple[int, int],
    rng: np.random.Generator,
) -> ActuatorParams:
    """Return per-actuator parameter maps: nominal * (1 + s N(0, 1)) for each spread field.

    Draws one standard-normal map per field of :data:`SPREADABLE` in a fixed order, so the
    same seed gives the same actuators whatever spread is switched on.
    """
    maps = nominal.as_arrays(shape)
    draws = {name: rng.standard_normal(shape) for name in SPREADABLE}
    return replace(
        maps,
        **{name: getattr(maps, name) * (1.0 + rel * draws[name]) for name, rel in spread.items()},
    )


class ActuatorGrid:
    """State and response of the actuator grid; one :meth:`apply` + :meth:`respond` per step."""

    def __init__(
        self,
        shape: tuple[int, int],
        *,
        config: ActuatorConfig,
        effects: Effects,
        dt: float,
        reference_temperature: float,
        rng: np.random.Generator,
    ) -> None:
        config.validate()
        self.shape = shape
        self.config = config
        self.effects = effects
        self.dt = dt
        self.substeps = config.substeps
        self.reference_temperature = reference_temperature
        nominal = config.params
        if effects.temperature_curvature.enabled:
            nominal = replace(
                nominal,
                m3=nominal.m3 + effects.temperature_curvature.m3,
                k3=nominal.k3 + effects.temperature_curvature.k3,
            )
        #: Per-actuator parameters (arrays of ``shape``) the plant really has.
        self.params = spread_params(nominal, config.spread, shape, rng)
        delay_steps = (
            round(effects.delay.delay_s * self.substeps / dt) if effects.delay.enabled else 0
        )
        # A delay of m internal steps = q whole plant steps and r internal steps.
        self._delay_whole, self._switch = divmod(delay_steps, self.substeps)
        self._history = np.zeros((self._delay_whole + 2, *shape))
        hyst = effects.hysteresis
        self._operators = [
            (getattr(hyst, w), getattr(hyst, r))
            for k, (w, r) in enumerate(operator_names(i) for i in range(MAX_OPERATORS))
            if k == 0 or getattr(hyst, w) > 0.0
        ]
        self._play = np.zeros((len(self._operators), *shape))
        self._mean_voltage = np.zeros(shape)
        self._mean_decay = float(np.exp(-dt / effects.self_heating.mean_window_s))
        dispersion = effects.frequency_dispersion
        self._relaxation_decay = relaxation_decay(dispersion.corner_hz, dt / self.substeps)
        #: Relaxation state of the drive (effect ``frequency_dispersion``) [V], (R, C).
        self._relaxation = np.zeros(shape)
        self.command = np.zeros(shape)
        #: Actuator heat from dielectric loss over the current step [W], (R, C).
        self.heating_power = np.zeros(shape)
        #: Voltages actually applied (after delay) before and after the in-step switch.
        self.voltage_before = np.zeros(shape)
        self.voltage_after = np.zeros(shape)

    def apply(self, command: FloatArray) -> None:
        """Latch ``command`` (R, C) [V] for the coming step: saturate, delay, compute loss."""
        self.command = np.clip(command, -self.config.v_limit, self.config.v_limit)
        hist = self._history
        hist[1:] = hist[:-1].copy()
        hist[0] = self.command
        # Applied voltage switches from u[k - q - 1] to u[k - q] at internal step r.
        self.voltage_before = hist[self._delay_whole + 1]
        self.voltage_after = hist[self._delay_whole]
        if self._switch == 0:
            self.voltage_before = self.voltage_after
        if self.effects.self_heating.enabled:
            previous = hist[self._delay_whole + 1]
            current = hist[self._delay_whole]
            swing = np.abs(current - previous)
            level = np.abs(0.5 * (current + previous) - self._mean_voltage)
            loss = self.effects.self_heating.loss_w_per_hz_v2
            self.heating_power = 0.5 * loss * swing * level / self.dt
            self._mean_voltage = current + (self._mean_voltage - current) * self._mean_decay

    def respond(
        self,
        T_start: FloatArray,
        T_end: FloatArray,
        t_start: float,
        all_substeps: bool = False,
    ) -> FloatArray:
        """Return displacements [m] over the step whose command :meth:`apply` latched.

        Args:
            T_start: actuator temperatures at the start of the step (R, C) [degC].
            T_end: actuator temperatures at the end of the step (R, C) [degC].
            t_start: run time at the start of the step [s] (for drift).
            all_substeps: return every internal step (n, R, C) instead of the end (1, R, C).

        """
        n = self.substeps
        dispersion = self.effects.frequency_dispersion
        # the relaxation filters every internal step, so then they are all computed
        every = all_substeps or dispersion.enabled
        ends = np.arange(1, n + 1) if every else np.array([n])
        frac = (ends / n)[:, None, None]
        T = T_start + frac * (T_end - T_start)
        before_switch = (ends - 1 < self._switch)[:, None, None]
        V = np.where(before_switch, self.voltage_before, self.voltage_after)
        hyst = self.effects.hysteresis
        if hyst.enabled:
            # Prandtl-Ishlinskii: operator 1 always, further ones where their weight is > 0
            total: FloatArray | float = 0.0
            mix: FloatArray | float = 0.0
            for k, (weight, threshold) in enumerate(self._operators):
                first = play(self._play[k], self.voltage_before, threshold)
                second = play(first, self.voltage_after, threshold)
                self._play[k] = second
                a = hysteresis_weight(T, self.params.Tm, weight)
                played = np.where(before_switch, first, second)
                total, mix = (a, a * played) if k == 0 else (total + a, mix + a * played)
            V = (1.0 - total) * V + mix
        if dispersion.enabled:
            V = np.array(np.broadcast_to(V, T.shape))
            for i in range(n):  # over time; vectorised over the grid
                drive = V[i].copy()
                V[i] = relaxation_output(drive, self._relaxation, dispersion.fraction)
                decay = self._relaxation_decay
                self._relaxation = relaxation_advance(drive, self._relaxation, decay)
        z = hyperbolic_forward(V, T, self.params)
        if self.effects.drift.enabled:
            times = np.asarray(t_start + ends * (self.dt / n), np.float64)
            drift = self.effects.drift
            z = z * drift_factor(times, drift.fraction, drift.tau_s, drift.nu)[:, None, None]
        if self.effects.coupling.enabled:
            z = z + self.effects.coupling.coefficient * grid_laplacian(z)
        if self.effects.thermal_expansion.enabled:
            alpha = self.effects.thermal_expansion.alpha_m_per_degc
            z = z + alpha * (T - self.reference_temperature)
        if every and not all_substeps:
            z = z[-1:]
        return np.asarray(z, np.float64)
