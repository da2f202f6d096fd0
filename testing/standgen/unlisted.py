"""Physical effects in no list of the product's registry (issue 34), as the stand applies them.

Each is plausible on a real rig and expressible, at least approximately, by a generic term
library (V, dV/dt, T, dT/dt, low-passes of V and V^2, the delayed command, neighbours'
temperatures, polynomial and trigonometric functions of these and of the modelled
displacement). Whether a feedforward can undo it, and from which side:

- ``slew_limit`` (amplifier: the drive's rate is limited): not beyond the limit (the
  amplifier cannot go faster); below it, drive side (pre-shaping the command).
- ``amplifier_droop`` (amplifier: gain falls with the output current ~ dV/dt): yes, drive
  side (the command boosted by the inverse of the droop).
- ``periodic_nonlinearity`` (interferometer: an error periodic in the displacement): no, a
  metrology error; the mirror is right, the measurement must be corrected instead.
- ``creep`` (actuator: logarithmic creep after each change): yes, drive side (the inverse
  of a linear filter on the strain).
- ``thermal_gradient`` (grid: the centre lags the Peltier; the sensors on the rim mounts
  miss it): yes, drive side (the law at a corrected temperature).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from standgen._typing import FloatArray
from standgen.operators import first_order_lag
from standgen.ranges import UNLISTED_FAMILIES, range_of

#: Helium-neon wavelength [m]: one fringe per lambda / 2 of mirror motion.
WAVELENGTH_M: Final = 633e-9
#: |dV/dt| [V/s] at which the amplifier's droop reaches its full strength.
DROOP_REFERENCE_V_PER_S: Final = 5e3
#: Time constants [s] of the creep's Prony series: one lag per decade from 10 ms.
CREEP_TAUS_S: Final = (0.01, 0.1, 1.0, 10.0)


class UnlistedError(ValueError):
    """An unknown unlisted effect, or one the grid cannot show."""


@dataclass(frozen=True)
class SlewLimit:
    """The amplifier's output changes by at most ``rate_v_per_s`` [V/s]."""

    rate_v_per_s: float


@dataclass(frozen=True)
class AmplifierDroop:
    """Gain droop with output current: V (1 - strength min(|dV/dt| / reference, 1))."""

    strength: float
    reference_v_per_s: float = DROOP_REFERENCE_V_PER_S


@dataclass(frozen=True)
class PeriodicNonlinearity:
    """Interferometer error a sin(4 pi z / lambda + phase) + a/4 sin(8 pi z / lambda + phase2)."""

    amplitude_m: float
    phase: float
    phase2: float
    wavelength_m: float = WAVELENGTH_M


@dataclass(frozen=True)
class Creep:
    """Logarithmic creep: z + gamma sum over ``taus_s`` of first-order lags of z."""

    gamma_per_decade: float
    taus_s: tuple[float, ...] = CREEP_TAUS_S


@dataclass(frozen=True)
class ThermalGradient:
    """Actuator T offset: -lag_s x depth x neighbours' mean dT/dt (depth 0 rim, 1 centre)."""

    lag_s: float


@dataclass(frozen=True)
class Unlisted:
    """The unlisted effects of one recording (``None``: absent)."""

    slew_limit: SlewLimit | None = None
    amplifier_droop: AmplifierDroop | None = None
    periodic_nonlinearity: PeriodicNonlinearity | None = None
    creep: Creep | None = None
    thermal_gradient: ThermalGradient | None = None

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the present effects, in :data:`UNLISTED_FAMILIES` order."""
        return tuple(n for n in UNLISTED_FAMILIES if getattr(self, n) is not None)

    def as_dict(self) -> dict[str, dict[str, Any]]:
        """Return ``{name: parameters}`` of the present effects (JSON-ready)."""
        return {n: asdict(getattr(self, n)) for n in self.names}


def draw_unlisted(names: Iterable[str], rng: np.random.Generator,
                  shape: tuple[int, int]) -> Unlisted:
    """Draw parameters for the unlisted effects ``names``.

    Raises:
        UnlistedError: an unknown name, or ``thermal_gradient`` on a grid smaller than 3 x 3
            (no actuator away from the rim).

    """
    wanted = tuple(names)
    unknown = sorted(set(wanted) - set(UNLISTED_FAMILIES))
    if unknown:
        raise UnlistedError(f"unknown unlisted effect(s) {unknown}; known: "
                            f"{list(UNLISTED_FAMILIES)}")
    if "thermal_gradient" in wanted and min(shape) < 3:
        raise UnlistedError(f"thermal_gradient needs a grid of at least 3 x 3, not {shape}")
    kwargs: dict[str, Any] = {}
    if "slew_limit" in wanted:
        kwargs["slew_limit"] = SlewLimit(range_of("slew_limit", "rate_v_per_s").draw(rng))
    if "amplifier_droop" in wanted:
        kwargs["amplifier_droop"] = AmplifierDroop(
            range_of("amplifier_droop", "strength").draw(rng))
    if "periodic_nonlinearity" in wanted:
        kwargs["periodic_nonlinearity"] = PeriodicNonlinearity(
            range_of("periodic_nonlinearity", "amplitude_m").draw(rng),
            float(rng.uniform(0, 2 * np.pi)), float(rng.uniform(0, 2 * np.pi)))
    if "creep" in wanted:
        kwargs["creep"] = Creep(range_of("creep", "gamma_per_decade").draw(rng))
    if "thermal_gradient" in wanted:
        kwargs["thermal_gradient"] = ThermalGradient(
            range_of("thermal_gradient", "lag_s").draw(rng))
    return Unlisted(**kwargs)


def slew_limited(v: npt.ArrayLike, dt: float, rate_v_per_s: float) -> FloatArray:
    """Return the amplifier's output following ``v`` (N, ...), |dV/dt| <= ``rate_v_per_s``.

    Starts on the input; each sample moves towards the input by at most rate x dt.
    """
    vs = np.asarray(v, np.float64)
    step = rate_v_per_s * dt
    out = np.empty_like(vs)
    state = vs[0].copy()
    for i in range(vs.shape[0]):
        state += np.clip(vs[i] - state, -step, step)
        out[i] = state
    return out


def drooped(v: npt.ArrayLike, dt: float, droop: AmplifierDroop) -> FloatArray:
    """Return the amplifier's output, its gain drooping with |dV/dt| (``v`` (N, ...) [V])."""
    vs = np.asarray(v, np.float64)
    rate = np.abs(np.gradient(vs, dt, axis=0))
    return np.asarray(vs * (1.0 - droop.strength * np.minimum(
        rate / droop.reference_v_per_s, 1.0)), np.float64)


def periodic_error(z: npt.ArrayLike, error: PeriodicNonlinearity) -> FloatArray:
    """Return the interferometer's periodic error [m] at true displacement ``z`` [m]."""
    zs = np.asarray(z, np.float64)
    phase = 4 * np.pi * zs / error.wavelength_m
    return np.asarray(error.amplitude_m * (np.sin(phase + error.phase)
                                           + 0.25 * np.sin(2 * phase + error.phase2)),
                      np.float64)


def crept(z: npt.ArrayLike, dt: float, creep: Creep) -> FloatArray:
    """Displacement ``z`` (N, ...) with logarithmic creep (a lag per decade of time)."""
    zs = np.asarray(z, np.float64)
    return np.asarray(zs + creep.gamma_per_decade * sum(
        first_order_lag(zs, dt, tau) for tau in creep.taus_s), np.float64)


def depth(shape: tuple[int, int]) -> FloatArray:
    """Distance of each cell from the grid's rim, 0 on the rim, 1 at the deepest cell."""
    rows, cols = shape
    r = np.minimum(np.arange(rows), np.arange(rows)[::-1])[:, None]
    c = np.minimum(np.arange(cols), np.arange(cols)[::-1])[None, :]
    d = np.minimum(r, c).astype(np.float64)
    return d / d.max() if d.max() > 0 else d


def gradient_offset(temperature: npt.ArrayLike, dt: float,
                    gradient: ThermalGradient) -> FloatArray:
    """Temperature offset (N, R, C) [degC] of each actuator behind its neighbours' dT/dt."""
    ts = np.asarray(temperature, np.float64)
    rate = np.gradient(ts, dt, axis=0)
    total = np.zeros_like(rate)
    count = np.zeros(ts.shape[1:])
    for axis, shift in ((1, 1), (1, -1), (2, 1), (2, -1)):
        mask = np.ones(ts.shape[1:], bool)
        index = [slice(None)] * 2
        index[axis - 1] = slice(0, 1) if shift == 1 else slice(-1, None)
        mask[tuple(index)] = False  # no neighbour on that side: np.roll would wrap
        total += np.roll(rate, shift, axis=axis) * mask
        count += mask
    mean = total / np.maximum(count, 1)
    shape = (int(ts.shape[1]), int(ts.shape[2]))
    return np.asarray(-gradient.lag_s * depth(shape) * mean, np.float64)
