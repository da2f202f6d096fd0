"""The feedforward's compensation parameters (pure numpy/scipy, no rclpy).

Every effect of :mod:`es_physics.effects` states its ``compensation.*`` parameters and
builds its compensation stage from them (:meth:`es_physics.effects.Effect.compensator`,
docs/architecture.md "Effects beyond the basic model"); the feedforward chains the stages
in model order. Built in: the temperature lead (``sensor_lag``, a Kalman filter), the set
point predicted over the delay, thermal expansion subtracted, the drift divided out, the
coupling solved,
and the drive's inverses (frequency dispersion, then the Prandtl-Ishlinskii hysteresis),
self-heating moving the temperature the law is evaluated at.

This module holds :class:`CompensationParams`, the typed set of those parameters (with
the values of effects added from other packages in :attr:`CompensationParams.extra`), their
ranges and descriptions, and re-exports the built-in compensation classes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from types import MappingProxyType
from typing import Final

from es_feedforward.errors import FeedforwardConfigError
from es_physics.effects import registry
from es_physics.effects.coupling import CouplingInverse, laplacian
from es_physics.effects.delay import DelayPredictor
from es_physics.effects.drift import compensated_drift
from es_physics.effects.frequency_dispersion import RelaxationInverse
from es_physics.effects.hysteresis import HysteresisInverse, compensated_operators
from es_physics.effects.sensor_lag import TemperatureLead

__all__ = [
    "DESCRIPTIONS",
    "PREFIX",
    "RANGES",
    "CompensationParams",
    "CouplingInverse",
    "DelayPredictor",
    "HysteresisInverse",
    "RelaxationInverse",
    "TemperatureLead",
    "drift_factor",
    "laplacian",
]

#: Name prefix of the compensation parameters (ROS parameters and parameter files).
PREFIX: Final = "compensation."


@dataclass(frozen=True)
class CompensationParams:
    """The ``compensation.*`` parameters; every effect is off at its default.

    The fields are the typed face of the compensation parameters that the effects of
    :mod:`es_physics.effects` declare (names, ranges and defaults are theirs; a test checks
    that the two agree).

    Attributes:
        temperature_lead_s: sensor lag tau to undo [s] (0 = off).
        temperature_lead_filter_s: smoothing time of the lead's Kalman filter [s].
        temperature_noise_degc: standard deviation of the temperature sensor's noise [degC].
        delay_s: transport delay to predict over [s] (0 = off).
        hysteresis_weight: weight a of the play operator, in [0, 0.9] (0 = off).
        hysteresis_threshold_v: half-width r of the play operator [V].
        hysteresis_weight_2, hysteresis_threshold_v_2, hysteresis_weight_3,
        hysteresis_threshold_v_3: the second and third operators of a Prandtl-Ishlinskii
            hysteresis (weight 0 = unused).
        hysteresis_decay_per_degc: beta of the weights' temperature law [1/degC] (0 = none).
        hysteresis_reference_temperature: temperature at which the weights hold [degC].
        coupling: coefficient c of the 4-neighbour Laplacian coupling (0 = off).
        thermal_expansion: expansion coefficient alpha [m/degC] (0 = off).
        expansion_reference_temperature: temperature of zero expansion [degC].
        drift_fraction: final relative loss a of M (0 = off).
        drift_tau_s: drift time constant tau [s].
        drift_nu: stretching exponent nu of the drift.
        drift_epoch_s: ROS time [s] at which the drift started (t = now - epoch).
        dispersion_fraction: relaxing fraction r of the gain (0 = off).
        dispersion_corner_hz: relaxation corner frequency f_c [Hz].
        self_heating_gain: excess actuator temperature per drive power measure
            [degC s/V^2] (0 = off).
        self_heating_tau_s: time constant of the excess temperature [s].
        self_heating_mean_window_s: running-mean window of the drive [s].
        discovered_<k>_coefficient, discovered_<k>_factor_a, discovered_<k>_parameter_a,
        discovered_<k>_factor_b, discovered_<k>_parameter_b, discovered_<k>_acts_on
            (k = 1, 2, 3): the calibration's discovered terms (es_physics.effects.discovered;
            coefficient 0 = unused; acts_on 0 displacement, 1 drive, 2 temperature).

    The compensation parameters of effects from other packages have no field: they are read
    as attributes too (their declared default unless :meth:`with_extra` gave them), and
    :meth:`values` and :meth:`replaced` include them (``dataclasses.replace`` does not).

    """

    temperature_lead_s: float = 0.0
    temperature_lead_filter_s: float = 0.5
    temperature_noise_degc: float = 0.02
    delay_s: float = 0.0
    hysteresis_weight: float = 0.0
    hysteresis_threshold_v: float = 0.0
    hysteresis_weight_2: float = 0.0
    hysteresis_threshold_v_2: float = 0.0
    hysteresis_weight_3: float = 0.0
    hysteresis_threshold_v_3: float = 0.0
    hysteresis_decay_per_degc: float = 0.0
    hysteresis_reference_temperature: float = 46.0
    coupling: float = 0.0
    thermal_expansion: float = 0.0
    expansion_reference_temperature: float = 46.0
    drift_fraction: float = 0.0
    drift_tau_s: float = 3600.0
    drift_nu: float = 1.0
    drift_epoch_s: float = 0.0
    dispersion_fraction: float = 0.0
    dispersion_corner_hz: float = 20.0
    self_heating_gain: float = 0.0
    self_heating_tau_s: float = 1.0
    self_heating_mean_window_s: float = 1.0
    discovered_1_coefficient: float = 0.0
    discovered_1_factor_a: float = 0.0
    discovered_1_parameter_a: float = 0.0
    discovered_1_factor_b: float = 0.0
    discovered_1_parameter_b: float = 0.0
    discovered_1_acts_on: float = 0.0
    discovered_2_coefficient: float = 0.0
    discovered_2_factor_a: float = 0.0
    discovered_2_parameter_a: float = 0.0
    discovered_2_factor_b: float = 0.0
    discovered_2_parameter_b: float = 0.0
    discovered_2_acts_on: float = 0.0
    discovered_3_coefficient: float = 0.0
    discovered_3_factor_a: float = 0.0
    discovered_3_parameter_a: float = 0.0
    discovered_3_factor_b: float = 0.0
    discovered_3_parameter_b: float = 0.0
    discovered_3_acts_on: float = 0.0

    def __post_init__(self) -> None:
        """Give the parameters declared beyond the typed fields their defaults."""
        object.__setattr__(self, "_extra", MappingProxyType(dict(_EXTRA_DEFAULTS)))

    @classmethod
    def with_extra(cls, extra: Mapping[str, float], **typed: float) -> CompensationParams:
        """Return the set with typed fields ``typed`` and the values ``extra`` of parameters.

        ``extra`` holds, by name without prefix, the parameters that effects from other
        packages declare (the declared default for any not given).

        Raises:
            FeedforwardConfigError: a name in ``extra`` that no effect declares beyond the
                typed fields.
            TypeError: a name in ``typed`` that is no field.

        """
        unknown = set(extra) - set(_EXTRA_DEFAULTS)
        if unknown:
            raise FeedforwardConfigError(f"unknown compensation parameter(s) {sorted(unknown)}")
        params = cls(**typed)
        full = {**_EXTRA_DEFAULTS, **{k: float(v) for k, v in extra.items()}}
        object.__setattr__(params, "_extra", MappingProxyType(full))
        return params

    def __getattr__(self, name: str) -> float:
        """Return the value of a parameter declared beyond the typed fields.

        Raises:
            AttributeError: no effect declares ``name``.

        """
        extra = self.__dict__.get("_extra")
        if extra is not None and name in extra:
            return float(extra[name])
        raise AttributeError(f"no compensation parameter {name!r}")

    def __eq__(self, other: object) -> bool:
        """Equal when every declared parameter has the same value."""
        if not isinstance(other, CompensationParams):
            return NotImplemented
        return self.values() == other.values()

    def __hash__(self) -> int:
        """Hash of every declared parameter's value."""
        return hash(tuple(sorted(self.values().items())))

    def values(self) -> dict[str, float]:
        """Return every declared compensation parameter's value by name (no prefix)."""
        return {name: float(getattr(self, name)) for name in RANGES}

    def of(self, effect_name: str) -> dict[str, float]:
        """Return the values of the compensation parameters effect ``effect_name`` declares."""
        return {p.name: float(getattr(self, p.name)) for p in registry()[effect_name].compensation}

    def replaced(self, values: Mapping[str, float]) -> CompensationParams:
        """Return a copy with the parameters named in ``values`` (no prefix) replaced.

        Raises:
            FeedforwardConfigError: an unknown name.

        """
        typed = {f.name for f in fields(self)}
        unknown = set(values) - set(RANGES)
        if unknown:
            raise FeedforwardConfigError(f"unknown compensation parameter(s) {sorted(unknown)}")
        kept = {f.name: getattr(self, f.name) for f in fields(self)}
        extra = {k: v for k, v in self.values().items() if k not in typed}
        for name, value in values.items():
            (kept if name in typed else extra)[name] = float(value)
        return CompensationParams.with_extra(extra, **kept)

    @classmethod
    def from_mapping(cls, values: dict[str, float]) -> CompensationParams:
        """Build from ``{name: value}`` with or without the ``compensation.`` prefix.

        Raises:
            FeedforwardConfigError: an unknown name or a value outside its range
                (see :data:`RANGES`).

        """
        known = {f.name for f in fields(cls)}
        kwargs: dict[str, float] = {}
        extra: dict[str, float] = {}
        for key, value in values.items():
            name = key.removeprefix(PREFIX)
            if name not in RANGES:
                raise FeedforwardConfigError(f"unknown compensation parameter {key!r}")
            (kwargs if name in known else extra)[name] = float(value)
        params = cls.with_extra(extra, **kwargs)
        reason = params.reason_to_reject()
        if reason is not None:
            raise FeedforwardConfigError(reason)
        return params

    def reason_to_reject(self) -> str | None:
        """Return why this set is not usable, or ``None``."""
        for name, (low, high) in RANGES.items():
            value = getattr(self, name)
            if not low <= value <= high:  # NaN fails too
                return f"{PREFIX}{name}={value!r} is outside [{low}, {high}]"
        if self.drift_fraction > 0.0 and self.drift_tau_s <= 0.0:
            return f"{PREFIX}drift_tau_s must be > 0 when drift_fraction > 0"
        if sum(self.hysteresis_operators()[0]) > 0.9:
            return f"{PREFIX}hysteresis weights sum to more than 0.9"
        return None

    def hysteresis_operators(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Return the (weights, thresholds [V]) of the hysteresis operators in use."""
        return compensated_operators(self.of("hysteresis"))


#: Accepted range of every compensation parameter (inclusive), from the effect registry.
RANGES: Final[dict[str, tuple[float, float]]] = {
    p.name: (p.low, p.high) for effect in registry().values() for p in effect.compensation
}
#: One line per compensation parameter: the declaring effect, what it is, its unit.
DESCRIPTIONS: Final[dict[str, str]] = {
    p.name: f"{effect.name}: {p.doc}" + (f" [{p.unit}]" if p.unit else "")
    for effect in registry().values()
    for p in effect.compensation
}


#: Defaults of the compensation parameters declared beyond the typed fields (effects added
#: by other packages).
_EXTRA_DEFAULTS: Final[dict[str, float]] = {
    p.name: p.default
    for effect in registry().values()
    for p in effect.compensation
    if p.name not in {f.name for f in fields(CompensationParams)}
}


def drift_factor(params: CompensationParams, t: float) -> float:
    """Return M_eff / M = 1 - a (1 - exp(-(t_rel / tau)^nu)) at ROS time ``t`` [s]."""
    return compensated_drift(
        t, params.drift_fraction, params.drift_tau_s, params.drift_nu, params.drift_epoch_s
    )
