"""Which effects a recording carries and their parameters, drawn from :mod:`standgen.ranges`."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass
from itertools import pairwise
from typing import Any

import numpy as np

from standgen.ranges import FAMILIES, range_of


class EffectSetError(ValueError):
    """An unknown effect name, or an effect the grid cannot show (coupling on 1 x 1)."""


@dataclass(frozen=True)
class Delay:
    """Transport delay [s] between the recorded command and the actuator's drive."""

    delay_s: float


@dataclass(frozen=True)
class Hysteresis:
    """Drive-side Prandtl-Ishlinskii operator: thresholds [V] and weights (>= 0, sum < 1)."""

    thresholds_v: tuple[float, ...]
    weights: tuple[float, ...]


@dataclass(frozen=True)
class SelfHeating:
    """Dielectric loss: excess gain f A^2 [degC/(V^2 Hz)] reached with time constant [s]."""

    gain: float
    tau_s: float


@dataclass(frozen=True)
class FrequencyDispersion:
    """Debye relaxation of the drive: strength (fraction lost far above the corner), corner."""

    strength: float
    corner_hz: float


@dataclass(frozen=True)
class SensorLag:
    """First-order lag [s] of the temperature sensor behind the actuator."""

    tau_s: float


@dataclass(frozen=True)
class Drift:
    """Aging of M: gain 1 - a + a exp(-(t/tau)^nu), t [s] from the start of the recording."""

    fraction: float
    tau_s: float
    nu: float


@dataclass(frozen=True)
class Coupling:
    """Face-sheet coupling z = z_free + c lap(z_free)."""

    coefficient: float


@dataclass(frozen=True)
class ThermalExpansion:
    """z += alpha (T_actuator - reference) [m/degC, degC]."""

    alpha_m_per_degc: float
    reference_degc: float = 40.0


@dataclass(frozen=True)
class TemperatureCurvature:
    """Quadratic T* terms m3 [m^2/V^2/degC^2] and k3 [m/V/degC^2]."""

    m3: float
    k3: float


@dataclass(frozen=True)
class Effects:
    """The effects of one recording (``None``: absent)."""

    delay: Delay | None = None
    hysteresis: Hysteresis | None = None
    self_heating: SelfHeating | None = None
    frequency_dispersion: FrequencyDispersion | None = None
    sensor_lag: SensorLag | None = None
    drift: Drift | None = None
    coupling: Coupling | None = None
    thermal_expansion: ThermalExpansion | None = None
    temperature_curvature: TemperatureCurvature | None = None

    @property
    def names(self) -> tuple[str, ...]:
        """Canonical names of the present effects, in :data:`FAMILIES` order."""
        return tuple(n for n in FAMILIES if getattr(self, n) is not None)

    def as_dict(self) -> dict[str, dict[str, Any]]:
        """Return ``{name: parameters}`` of the present effects (JSON-ready)."""
        return {n: asdict(getattr(self, n)) for n in self.names}


def _draw(family: str, name: str, rng: np.random.Generator) -> float:
    return range_of(family, name).draw(rng)


def draw_delay(rng: np.random.Generator, rate_hz: float) -> Delay:
    """Draw a delay of 0.3-15 command periods whose fractional part is in [0.15, 0.85]."""
    row = range_of("delay", "delay_samples")
    while True:
        samples = float(np.floor(rng.uniform(row.low, row.high))) + rng.uniform(0.15, 0.85)
        if row.low <= samples <= row.high:
            return Delay(samples / rate_hz)


def draw_hysteresis(rng: np.random.Generator) -> Hysteresis:
    """Draw 1-3 play operators with distinct thresholds and random non-negative weights."""
    count_row = range_of("hysteresis", "operators")
    count = int(rng.integers(int(count_row.low), int(count_row.high) + 1))
    row = range_of("hysteresis", "threshold_v")
    # distinct thresholds: split the range into `count` bands, one threshold per band
    edges = np.linspace(row.low, row.high, count + 1)
    thresholds = tuple(float(rng.uniform(a, b)) for a, b in pairwise(edges))
    total = _draw("hysteresis", "total_weight", rng)
    split = rng.dirichlet(np.full(count, 2.0))
    return Hysteresis(thresholds, tuple(float(total * s) for s in split))


def draw_effects(names: Iterable[str], rng: np.random.Generator, *, rate_hz: float,
                 duration_s: float, shape: tuple[int, int]) -> Effects:
    """Draw parameters for the effects ``names`` (canonical names).

    Raises:
        EffectSetError: an unknown name, or ``coupling`` on a grid smaller than 2 x 2.

    """
    wanted = tuple(names)
    unknown = sorted(set(wanted) - set(FAMILIES))
    if unknown:
        raise EffectSetError(f"unknown effect(s) {unknown}; known: {list(FAMILIES)}")
    if "coupling" in wanted and min(shape) < 2:
        raise EffectSetError(f"coupling needs a grid of at least 2 x 2, not {shape}")
    kwargs: dict[str, Any] = {}
    for name in FAMILIES:
        if name not in wanted:
            continue
        if name == "delay":
            kwargs[name] = draw_delay(rng, rate_hz)
        elif name == "hysteresis":
            kwargs[name] = draw_hysteresis(rng)
        elif name == "self_heating":
            kwargs[name] = SelfHeating(_draw(name, "gain", rng), _draw(name, "tau_s", rng))
        elif name == "frequency_dispersion":
            kwargs[name] = FrequencyDispersion(_draw(name, "strength", rng),
                                               _draw(name, "corner_hz", rng))
        elif name == "sensor_lag":
            kwargs[name] = SensorLag(_draw(name, "tau_s", rng))
        elif name == "drift":
            kwargs[name] = Drift(_draw(name, "fraction", rng),
                                 _draw(name, "tau_fraction", rng) * duration_s,
                                 _draw(name, "nu", rng))
        elif name == "coupling":
            kwargs[name] = Coupling(_draw(name, "coefficient", rng))
        elif name == "thermal_expansion":
            kwargs[name] = ThermalExpansion(_draw(name, "alpha_m_per_degc", rng))
        else:
            signs = rng.choice([-1.0, 1.0], size=2)
            kwargs[name] = TemperatureCurvature(float(signs[0] * _draw(name, "m3_abs", rng)),
                                                float(signs[1] * _draw(name, "k3_abs", rng)))
    return Effects(**kwargs)
