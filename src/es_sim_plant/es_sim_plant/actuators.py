"""The actuator grid: per-actuator hyperbolic model, manufacturing spread, amplifier, effects.

Each actuator follows z = (M L / k^2) tanh^2(k V / L) with M(T), k(T) from
:mod:`es_physics.params` / :mod:`es_physics.laws` (the same library the
feedforward inverts). The nominal parameters get a seeded relative spread per actuator
(manufacturing scatter; default 2 % on m2, 1 % on k2, so gains scatter by ~2 %).

Time: a plant step of ``dt`` is split into ``substeps`` internal steps (default 10: 1 kHz at
a 100 Hz control rate). The amplifier holds the command over the step and saturates at
``v_limit``; the transport delay is resolved to one internal step, so within a plant step the
applied voltage switches once, from the older to the newer delayed command, at a known
internal step. The effects that are on act through their stages
(:mod:`es_physics.effects.stages`, built by :meth:`es_sim_plant.effects.Effects.stages`, in
model order): on the law's coefficients, the command's delay, the heat of the drive, the
voltage in effect (e.g. hysteresis, evaluated exactly since the applied voltage switches once
per step; a relaxation that needs every internal step) and the displacement after the law.
Displacements can be returned for every internal step (a high-rate "interferometer") or only
for the end of the step.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from es_common.arrays import FloatArray
from es_physics.effects import Drive, PlantContext, StepState
from es_physics.laws import DEFAULT_V_LIMIT, hyperbolic_forward
from es_physics.params import ActuatorParams
from es_sim_plant.effects import Effects
from es_sim_plant.errors import ScenarioError

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
        context = PlantContext(shape, dt, self.substeps, reference_temperature)
        #: The stages of the effects that are on, in model order.
        self.stages = effects.stages(context)
        nominal = config.params
        for stage in self.stages:
            nominal = stage.law(nominal)
        #: Per-actuator parameters (arrays of ``shape``) the plant really has.
        self.params = spread_params(nominal, config.spread, shape, rng)
        lags = [lag for lag in (s.sensor_lag_s() for s in self.stages) if lag is not None]
        #: First-order lag [s] of the temperature sensors behind the actuators, or None.
        self.sensor_lag_s: float | None = lags[0] if lags else None
        delay_steps = sum(stage.transport_steps() for stage in self.stages)
        # A delay of m internal steps = q whole plant steps and r internal steps.
        self._delay_whole, self._switch = divmod(delay_steps, self.substeps)
        self._history = np.zeros((self._delay_whole + 2, *shape))
        self._every_substep = any(stage.every_substep for stage in self.stages)
        self.command = np.zeros(shape)
        #: Actuator heat from the drive over the current step [W], (R, C); None when no
        #: effect heats the actuators.
        self.heating_power: FloatArray | None = None
        zero = np.zeros(shape)
        self._drive = Drive(zero, zero, zero, zero)

    @property
    def voltage_before(self) -> FloatArray:
        """Voltage applied (after delay) before the in-step switch [V] (R, C)."""
        return self._drive.before

    @property
    def voltage_after(self) -> FloatArray:
        """Voltage applied (after delay) after the in-step switch [V] (R, C)."""
        return self._drive.after

    def apply(self, command: FloatArray) -> None:
        """Latch ``command`` (R, C) [V] for the coming step: saturate, delay, compute heat."""
        self.command = np.clip(command, -self.config.v_limit, self.config.v_limit)
        hist = self._history
        hist[1:] = hist[:-1].copy()
        hist[0] = self.command
        # Applied voltage switches from u[k - q - 1] to u[k - q] at internal step r.
        previous = hist[self._delay_whole + 1]
        current = hist[self._delay_whole]
        before = current if self._switch == 0 else previous
        self._drive = Drive(previous, current, before, current)
        heat = [h for h in (stage.heating(self._drive) for stage in self.stages) if h is not None]
        if heat:
            total = heat[0]
            for h in heat[1:]:
                total = total + h
            self.heating_power = total

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
        # a stage that filters in time needs every internal step, so then they are all computed
        every = all_substeps or self._every_substep
        ends = np.arange(1, n + 1) if every else np.array([n])
        frac = (ends / n)[:, None, None]
        T = T_start + frac * (T_end - T_start)
        before_switch = (ends - 1 < self._switch)[:, None, None]
        drive = self._drive
        V = np.where(before_switch, drive.before, drive.after)
        step = StepState(
            drive=drive,
            T=T,
            times=np.asarray(t_start + ends * (self.dt / n), np.float64),
            before_switch=before_switch,
            params=self.params,
            reference_temperature=self.reference_temperature,
        )
        for stage in self.stages:
            V = stage.drive(V, step)
        z = hyperbolic_forward(V, T, self.params)
        for stage in self.stages:
            z = stage.displacement(z, step)
        if every and not all_substeps:
            z = z[-1:]
        return np.asarray(z, np.float64)
