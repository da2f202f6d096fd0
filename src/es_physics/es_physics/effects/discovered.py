"""A data-driven effect: terms the calibration found in its residual, added to the displacement.

The calibration's discovery step (es_calibration.discovery) searches a library of generic
terms for what the registry's effects leave in the held-out residual. A term is a
coefficient times one or two *factors*; a factor is one signal of the drive, the temperature
or the displacement (:data:`FACTORS`, one definition: the calibration builds its library
from it and the feedforward undoes the same terms). A factor has one parameter whose meaning
the factor states (a low-pass's time constant, a delay, a length, a reference temperature, an
epoch).

Compensation: ``compensation.discovered_<k>_*`` for up to :data:`SLOTS` terms (coefficient
0 = slot unused). Only terms whose every factor is known before the command is computed can
be undone from the set point (:attr:`Factor.compensable`): functions of the set point, the
temperatures and their rates, the time, and the drive's past (low-passes, delayed commands);
their sum is subtracted from the set point. A term of the present command (V, dV/dt, the
neighbours' commands) would need the numeric inverse of the augmented law: it is reported
but never written.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar, Final

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role
from es_physics.effects.stages import Compensator


@dataclass(frozen=True)
class Factor:
    """One signal a discovered term may multiply.

    Attributes:
        code: the number that names it in the parameters file (1..len(FACTORS)).
        key: short name (the term's expression uses it).
        unit: its unit.
        parameter: what its parameter is ("" when it has none).
        side: "output" (a function of the set point, temperatures, time or the drive's past)
            or "drive" (of the present command).
        compensable: the feedforward can evaluate it before the command is computed.
        mechanism: the physical mechanism a term of this factor points to, in words.

    """

    code: int
    key: str
    unit: str
    parameter: str
    side: str
    compensable: bool
    mechanism: str


#: Every factor, by code (one definition for the calibration's library and the feedforward).
FACTORS: Final[tuple[Factor, ...]] = (
    Factor(1, "V", "V", "", "drive", False,
           "the present command: a drive gain or offset the law lacks"),
    Factor(2, "dV/dt", "V/s", "", "drive", False,
           "the command's rate: a rate-dependent (viscous) response of the actuator"),
    Factor(3, "T", "degC", "reference temperature [degC]", "output", True,
           "the actuator temperature: a thermal strain or metrology drift with temperature"),
    Factor(4, "dT/dt", "degC/s", "", "output", True,
           "the temperature's rate: a thermal gradient through the actuator or its mount"),
    Factor(5, "t", "s", "epoch [s]", "output", True,
           "the time since the start: a slow drift of the stand or the metrology"),
    Factor(6, "z", "m", "", "output", True,
           "the modelled displacement: a gain error of the displacement metrology"),
    Factor(7, "nbr(V)", "V", "", "drive", False,
           "the neighbours' commands: a mechanical or electrical cross-talk across the grid"),
    Factor(8, "nbr(T)-T", "degC", "", "output", True,
           "the neighbours' temperature minus the actuator's: a thermal gradient across the grid"),
    Factor(9, "nbr(dT/dt)", "degC/s", "", "output", True,
           "the neighbours' dT/dt: a thermal gradient across the grid"),
    Factor(10, "LP(V)", "V", "time constant [s]", "output", True,
           "a low-pass of V: a slow (creep-like) response of the actuator to its drive"),
    Factor(11, "LP(V^2)", "V^2", "time constant [s]", "output", True,
           "a low-pass of V^2: self-heating of the actuator by its drive"),
    Factor(12, "V(t-d)", "V", "delay [s]", "output", True,
           "the command delayed: a delay or lag in the drive"),
    Factor(13, "sin(2 pi z/l)", "", "length [m]", "output", True,
           "sin of the displacement over a length: an interferometer's periodic nonlinearity"),
    Factor(14, "cos(2 pi z/l)", "", "length [m]", "output", True,
           "cos of the displacement over a length: an interferometer's periodic nonlinearity"),
)
BY_CODE: Final[dict[int, Factor]] = {f.code: f for f in FACTORS}
#: Terms the parameters file can carry.
SLOTS: Final = 3


def neighbour_mean(x: FloatArray) -> FloatArray:
    """Return the mean of each element's existing 4-neighbours over the last two axes (R, C).

    A grid of one element is its own neighbour (the mean is the element itself).
    """
    total = np.zeros_like(x)
    count = np.zeros(x.shape[-2:])
    total[..., 1:, :] += x[..., :-1, :]
    count[1:, :] += 1
    total[..., :-1, :] += x[..., 1:, :]
    count[:-1, :] += 1
    total[..., :, 1:] += x[..., :, :-1]
    count[:, 1:] += 1
    total[..., :, :-1] += x[..., :, 1:]
    count[:, :-1] += 1
    return np.where(count > 0, total / np.maximum(count, 1), x)


@dataclass(frozen=True)
class Term:
    """A coefficient times one or two factors (each (code, parameter)); ``b`` is None alone."""

    coefficient: float
    a: tuple[int, float]
    b: tuple[int, float] | None = None

    @property
    def factors(self) -> tuple[tuple[int, float], ...]:
        """Return the term's (code, parameter) factors."""
        return (self.a,) if self.b is None else (self.a, self.b)

    @property
    def compensable(self) -> bool:
        """Whether the feedforward can undo the term from the set point."""
        return all(BY_CODE[c].compensable for c, _ in self.factors)


def expression(factors: Sequence[tuple[int, float]]) -> str:
    """Return the factors as text, e.g. ``LP(V^2)[tau=0.8 s] * T[ref=45 degC]``."""
    parts = []
    for code, value in factors:
        f = BY_CODE[code]
        name = f.parameter.split(" [")[0]
        parts.append(f"{f.key}[{name}={value:.4g}]" if f.parameter else f.key)
    return " * ".join(parts)


def unit(factors: Sequence[tuple[int, float]]) -> str:
    """Return the coefficient's unit: m per the factors' units."""
    units = [BY_CODE[c].unit for c, _ in factors if BY_CODE[c].unit]
    return "m" if not units else "m/(" + " ".join(units) + ")"


def _slot_parameters(k: int) -> tuple[Parameter, ...]:
    codes = float(len(FACTORS))
    return (
        Parameter(f"discovered_{k}_coefficient", "", -1.0, 1.0, 0.0,
                  f"term {k}: coefficient [m per the factors' units] (0 = unused)"),
        Parameter(f"discovered_{k}_factor_a", "", 0.0, codes, 0.0,
                  f"term {k}: first factor's code (es_physics.effects.discovered.FACTORS)"),
        Parameter(f"discovered_{k}_parameter_a", "", -1e12, 1e12, 0.0,
                  f"term {k}: first factor's parameter"),
        Parameter(f"discovered_{k}_factor_b", "", 0.0, codes, 0.0,
                  f"term {k}: second factor's code (0 = none)"),
        Parameter(f"discovered_{k}_parameter_b", "", -1e12, 1e12, 0.0,
                  f"term {k}: second factor's parameter"),
    )


def terms_from_values(values: Mapping[str, float]) -> list[Term]:
    """Return the terms the ``compensation.discovered_*`` values (no prefix) hold."""
    terms = []
    for k in range(1, SLOTS + 1):
        coefficient = float(values.get(f"discovered_{k}_coefficient", 0.0))
        code_a = round(values.get(f"discovered_{k}_factor_a", 0.0))
        if coefficient == 0.0 or code_a not in BY_CODE:
            continue
        code_b = round(values.get(f"discovered_{k}_factor_b", 0.0))
        b = (code_b, float(values[f"discovered_{k}_parameter_b"])) if code_b in BY_CODE else None
        terms.append(Term(coefficient, (code_a, float(values[f"discovered_{k}_parameter_a"])), b))
    return terms


def values_from_terms(terms: Sequence[Term]) -> dict[str, float]:
    """Return the ``compensation.discovered_*`` values (no prefix) for up to SLOTS terms."""
    values: dict[str, float] = {}
    for k, term in enumerate(terms[:SLOTS], start=1):
        b = term.b or (0, 0.0)
        values.update({
            f"discovered_{k}_coefficient": term.coefficient,
            f"discovered_{k}_factor_a": float(term.a[0]),
            f"discovered_{k}_parameter_a": term.a[1],
            f"discovered_{k}_factor_b": float(b[0]),
            f"discovered_{k}_parameter_b": b[1],
        })
    return values


class DiscoveredCompensation(Compensator):
    """The discovered terms subtracted from the set point (vectorised over the grid).

    State: the temperature rate from consecutive estimates (:meth:`measured_temperature`),
    one low-pass per (signal, time constant) and the recent commands (for delayed ones),
    advanced in :meth:`commit` with the command held between commands.
    """

    def __init__(self, terms: Sequence[Term], shape: tuple[int, int],
                 last_voltage: FloatArray | None = None) -> None:
        self.terms = [t for t in terms if t.compensable]
        self.shape = shape
        start = np.zeros(shape) if last_voltage is None else np.asarray(last_voltage, np.float64)
        self._lowpass: dict[tuple[int, float], FloatArray] = {
            (c, p): (start**2 if c == 11 else start.copy())
            for t in self.terms for c, p in t.factors if c in (10, 11)
        }
        delays = [p for t in self.terms for c, p in t.factors if c == 12]
        self._max_delay = max(delays, default=0.0)
        self._sent: deque[tuple[float, FloatArray]] = deque()
        self._last = start
        self._last_t: float | None = None
        self._temperature: tuple[float, FloatArray] | None = None
        self._rate = np.zeros(shape)

    def carry_over(self, previous: DiscoveredCompensation) -> None:
        """Take ``previous``'s state (copied: it stays usable) where the terms share it."""
        for key in self._lowpass.keys() & previous._lowpass.keys():
            self._lowpass[key] = previous._lowpass[key].copy()
        self._sent = deque(previous._sent)
        self._last, self._last_t = previous._last.copy(), previous._last_t
        self._temperature, self._rate = previous._temperature, previous._rate.copy()

    def measured_temperature(self, T: FloatArray, t: float) -> FloatArray:
        """Keep the temperature's rate from this estimate and the one before."""
        if self._temperature is not None and t > self._temperature[0]:
            rate = (T - self._temperature[1]) / (t - self._temperature[0])
            self._rate = np.where(np.isfinite(rate), rate, 0.0)
        self._temperature = (t, np.asarray(T, np.float64).copy())
        return T

    def _lowpass_at(self, key: tuple[int, float], t: float) -> FloatArray:
        """Return the low-pass ``key`` at ``t`` with the last command held since it was sent."""
        y = self._lowpass[key]
        if self._last_t is None:
            return y
        x = self._last**2 if key[0] == 11 else self._last
        return x + (y - x) * np.exp(-max(t - self._last_t, 0.0) / key[1])

    def _delayed(self, delay: float, t: float) -> FloatArray:
        """Return the command in force at ``t - delay`` (the oldest kept before that)."""
        chosen = self._last
        for sent_t, value in reversed(self._sent):
            chosen = value
            if sent_t <= t - delay + 1e-9:
                break
        return chosen

    def _factor(self, code: int, parameter: float, z: FloatArray, T: FloatArray,
                t: float) -> FloatArray | float:
        if code == 3:
            return T - parameter
        if code == 4:
            return self._rate
        if code == 5:
            return t - parameter
        if code == 6:
            return z
        if code == 8:
            return neighbour_mean(T) - T
        if code == 9:
            return neighbour_mean(self._rate)
        if code in (10, 11):
            return self._lowpass_at((code, parameter), t)
        if code == 12:
            return self._delayed(parameter, t)
        phase = 2.0 * np.pi * z / parameter
        return np.sin(phase) if code == 13 else np.cos(phase)

    def setpoint(self, z: FloatArray, T: FloatArray, t: float) -> FloatArray:
        """Return z minus the discovered terms (a non-finite term counts as 0)."""
        total = np.zeros(self.shape)
        for term in self.terms:
            value: FloatArray | float = term.coefficient
            for code, parameter in term.factors:
                value = value * self._factor(code, parameter, z, T, t)
            total = total + value
        return np.asarray(z - np.where(np.isfinite(total), total, 0.0), np.float64)

    def commit(self, sent: FloatArray, drive: FloatArray, t: float) -> FloatArray:
        """Advance the low-passes over the held command and keep ``sent``."""
        for key in self._lowpass:
            self._lowpass[key] = self._lowpass_at(key, t)
        self._last = np.asarray(sent, np.float64).copy()
        self._last_t = t
        if self._max_delay > 0.0:
            self._sent.append((t, self._last))
            while len(self._sent) > 2 and self._sent[1][0] <= t - self._max_delay - 1e-9:
                self._sent.popleft()
        return drive


class Discovered(Effect):
    """Terms found in the residual by the calibration's discovery step (no fixed physics)."""

    name: ClassVar[str] = "discovered"
    summary: ClassVar[str] = "data-driven terms the calibration found beyond the registry"
    role: ClassVar[Role] = Role.PLANT_ONLY
    compensation: ClassVar[tuple[Parameter, ...]] = tuple(
        p for k in range(1, SLOTS + 1) for p in _slot_parameters(k)
    )

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return the fitted values as they are (the terms carry their own meaning)."""
        return {k: float(v) for k, v in fit.values.items()}

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the terms' subtraction from the set point, or None when no term is set."""
        terms = [t for t in terms_from_values(values) if t.compensable]
        if not terms:
            return None
        stage = DiscoveredCompensation(terms, shape, last_voltage)
        if isinstance(previous, DiscoveredCompensation):
            stage.carry_over(previous)
        return stage
