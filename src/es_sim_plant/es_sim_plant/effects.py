"""Effects the basic hyperbolic model leaves out, as the plant implements them.

One definition for plant, calibration and feedforward: ``docs/architecture.md``, section
"Effects beyond the basic model". Each effect is off by default and switched on by a scenario
(``effects.<name>.enabled``) or a node parameter. This module holds their parameters and the
vectorised pieces the actuator grid and the sensors compose; it has no state of its own.

Symbols: T_a actuator temperature [degC], V applied command [V], z_free the displacement of
the basic hyperbolic model [m].
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from es_feedforward.calibration.model import CANDIDATES

FloatArray = npt.NDArray[np.float64]

#: Canonical effect names, in the order of docs/architecture.md: the calibration tool's
#: candidates plus self-heating, which only the plant has.
EFFECT_NAMES: Final = (*CANDIDATES, "self_heating")

#: Hysteresis weight a = a0 exp(-(T_a - Tm - HYSTERESIS_ONSET) / HYSTERESIS_DECAY): grows below.
HYSTERESIS_ONSET: Final = 2.0
HYSTERESIS_DECAY: Final = 4.0


@dataclass(frozen=True)
class SensorLag:
    """Sensor reads T_s with dT_s/dt = (T_a - T_s) / tau (sensor bonded beside the actuator).

    ``tau_s`` [s] is a thermal time: the scenario's ``time_scale`` multiplies it.
    """

    enabled: bool = False
    tau_s: float = 5.0


@dataclass(frozen=True)
class Delay:
    """Actuator responds to V(t - d); d [s] resolved to the internal integration step.

    The default is the thesis set-up's 12 samples at 5 kHz (2.4 ms).
    """

    enabled: bool = False
    delay_s: float = 2.4e-3


@dataclass(frozen=True)
class Hysteresis:
    """V_eff = (1 - a) V + a play_r(V), a = weight * exp(-(T_a - Tm - 2) / 4 degC).

    ``weight`` is a at T_a = Tm + 2 degC (clipped to [0, 1] at any T); ``threshold_v`` the
    play operator's half-width r [V]. Above Tm hysteresis falls below ~2 % (physics brief),
    hence the default weight 0.1 at Tm + 2 that decays to 0.5 % at Tm + 14.
    """

    enabled: bool = False
    weight: float = 0.1
    threshold_v: float = 30.0


@dataclass(frozen=True)
class Coupling:
    """z = z_free + c lap(z_free), lap the 4-neighbour graph Laplacian (face-sheet stiffness)."""

    enabled: bool = False
    coefficient: float = 0.05


@dataclass(frozen=True)
class ThermalExpansion:
    """z += alpha (T_a - T_ref), T_ref the scenario's initial base temperature.

    Default 0.4 nm/degC: 2e-6 /degC (PMN-PT range 1.6-3.2e-6) over L = 0.2 mm.
    """

    enabled: bool = False
    alpha_m_per_degc: float = 0.4e-9


@dataclass(frozen=True)
class Drift:
    """M_eff(t) = M(T) (1 - a (1 - exp(-(t / tau)^nu))), t from the start of the run (aging).

    ``tau_s`` is scaled by the scenario's ``time_scale``.
    """

    enabled: bool = False
    fraction: float = 0.03
    tau_s: float = 300.0
    nu: float = 0.5


@dataclass(frozen=True)
class TemperatureCurvature:
    """Quadratic T* terms of M(T*) and k(T*), added to the actuators' m3, k3.

    Defaults change M by ~-13 % and k by ~+5 % at T* = 14 degC relative to the linear laws
    (of the order of the scatter of the thesis's quadratic-in-T fits around the linear ones).
    """

    enabled: bool = False
    m3: float = 1.0e-18
    k3: float = 0.3e-9


@dataclass(frozen=True)
class SelfHeating:
    """Dielectric loss heats each actuator: P = p_d f V_amp^2 for a sine drive of frequency f.

    For any drive the plant uses the equivalent p_d |V - V_mean| |dV/dt| / 2 (V_mean a 1 s
    running mean), whose average over a sine period is exactly p_d f V_amp^2. Default
    p_d = pi C tan(delta) with C = 0.05 uF and tan(delta) = 0.03: 4.7e-9 W/(Hz V^2), about
    47 mW per actuator at 100 V amplitude and 1 kHz, negligible at 1 Hz.
    """

    enabled: bool = False
    loss_w_per_hz_v2: float = 4.7e-9
    mean_window_s: float = 1.0


@dataclass(frozen=True)
class Effects:
    """Switches and parameters of every effect (all off by default)."""

    sensor_lag: SensorLag = field(default_factory=SensorLag)
    delay: Delay = field(default_factory=Delay)
    hysteresis: Hysteresis = field(default_factory=Hysteresis)
    coupling: Coupling = field(default_factory=Coupling)
    thermal_expansion: ThermalExpansion = field(default_factory=ThermalExpansion)
    drift: Drift = field(default_factory=Drift)
    temperature_curvature: TemperatureCurvature = field(default_factory=TemperatureCurvature)
    self_heating: SelfHeating = field(default_factory=SelfHeating)

    def enabled_names(self) -> list[str]:
        """Return the canonical names of the effects that are on."""
        return [name for name in EFFECT_NAMES if getattr(self, name).enabled]

    def with_switches(self, switches: dict[str, bool]) -> Effects:
        """Return a copy with ``enabled`` of the named effects replaced.

        Raises:
            ValueError: an unknown effect name.

        """
        unknown = set(switches) - set(EFFECT_NAMES)
        if unknown:
            raise ValueError(f"unknown effect(s) {sorted(unknown)}; known: {list(EFFECT_NAMES)}")
        return replace(
            self,
            **{
                name: replace(getattr(self, name), enabled=bool(on))
                for name, on in switches.items()
            },
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> Effects:
        """Build from a scenario's ``effects`` mapping (``{name: {enabled: .., param: ..}}``).

        Raises:
            ValueError: unknown effect or parameter names, or non-numeric values.

        """
        data = data or {}
        if not isinstance(data, dict):
            raise ValueError("effects must be a mapping of effect name -> settings")
        unknown = set(data) - set(EFFECT_NAMES)
        if unknown:
            raise ValueError(f"unknown effect(s) {sorted(unknown)}; known: {list(EFFECT_NAMES)}")
        built: dict[str, object] = {}
        for name, raw in data.items():
            default = getattr(cls(), name)
            settings = {"enabled": raw} if isinstance(raw, bool) else (raw or {})
            if not isinstance(settings, dict):
                raise ValueError(f"effects.{name} must be a mapping or a boolean")
            known = {f.name for f in fields(default)}
            bad = set(settings) - known
            if bad:
                raise ValueError(
                    f"effects.{name}: unknown key(s) {sorted(bad)}; known {sorted(known)}"
                )
            values: dict[str, object] = {}
            for key, value in settings.items():
                if key == "enabled":
                    values[key] = bool(value)
                else:
                    try:
                        values[key] = float(value)
                    except (TypeError, ValueError):
                        raise ValueError(f"effects.{name}.{key} must be a number") from None
            built[name] = replace(default, **values)
        effects = cls(**built)  # type: ignore[arg-type]
        effects.validate()
        return effects

    def validate(self) -> None:
        """Raise ``ValueError`` when a parameter of an effect is out of its physical range."""
        checks = [
            (self.sensor_lag.tau_s > 0.0, "effects.sensor_lag.tau_s must be > 0"),
            (self.delay.delay_s >= 0.0, "effects.delay.delay_s must be >= 0"),
            (0.0 <= self.hysteresis.weight <= 1.0, "effects.hysteresis.weight must be in [0, 1]"),
            (self.hysteresis.threshold_v >= 0.0, "effects.hysteresis.threshold_v must be >= 0"),
            (
                0.0 <= self.coupling.coefficient < 0.125,
                "effects.coupling.coefficient must be in [0, 0.125) (keeps I + c lap invertible)",
            ),
            (0.0 <= self.drift.fraction < 1.0, "effects.drift.fraction must be in [0, 1)"),
            (self.drift.tau_s > 0.0, "effects.drift.tau_s must be > 0"),
            (self.drift.nu > 0.0, "effects.drift.nu must be > 0"),
            (self.self_heating.loss_w_per_hz_v2 >= 0.0, "effects.self_heating.loss must be >= 0"),
            (self.self_heating.mean_window_s > 0.0, "effects.self_heating.mean_window_s > 0"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)

    def time_scaled(self, time_scale: float) -> Effects:
        """Return a copy whose slow (thermal, aging) times are multiplied by ``time_scale``."""
        return replace(
            self,
            sensor_lag=replace(self.sensor_lag, tau_s=self.sensor_lag.tau_s * time_scale),
            drift=replace(self.drift, tau_s=self.drift.tau_s * time_scale),
        )


def grid_laplacian(z: FloatArray) -> FloatArray:
    """Return the 4-neighbour Laplacian sum(neighbours) - n_neighbours z (last two axes).

    Edges use only existing neighbours (the face sheet ends at the grid border).
    """
    lap = np.zeros_like(z)
    lap[..., 1:, :] += z[..., :-1, :] - z[..., 1:, :]
    lap[..., :-1, :] += z[..., 1:, :] - z[..., :-1, :]
    lap[..., :, 1:] += z[..., :, :-1] - z[..., :, 1:]
    lap[..., :, :-1] += z[..., :, 1:] - z[..., :, :-1]
    return lap


def hysteresis_weight(T: FloatArray, Tm: float | FloatArray, weight: float) -> FloatArray:
    """Return a = weight exp(-(T - Tm - 2) / 4), clipped to [0, 1]."""
    a = weight * np.exp(-(T - Tm - HYSTERESIS_ONSET) / HYSTERESIS_DECAY)
    return np.asarray(np.clip(a, 0.0, 1.0), np.float64)


def play(previous: FloatArray, V: FloatArray, threshold: float) -> FloatArray:
    """Return the backlash (play) operator output for input V given its previous output."""
    return np.asarray(np.clip(previous, V - threshold, V + threshold), np.float64)


def drift_factor(t: FloatArray | float, drift: Drift) -> FloatArray:
    """Return M_eff / M = 1 - a (1 - exp(-(t / tau)^nu)) at run time(s) t >= 0."""
    tt = np.maximum(np.asarray(t, np.float64), 0.0)
    return np.asarray(
        1.0 - drift.fraction * (1.0 - np.exp(-((tt / drift.tau_s) ** drift.nu))), np.float64
    )
