"""A data-driven effect: terms the calibration found in its residual, added to the displacement.

The calibration's discovery step (es_calibration.discovery) searches a library of generic
terms for what the registry's effects leave in the held-out residual. A term is a
coefficient times one or two *factors*; a factor is one signal of the drive, the temperature
or the displacement (:data:`FACTORS`, one definition: the calibration builds its library
from it and the feedforward undoes the same terms). A factor has one parameter whose meaning
the factor states (a low-pass's time constant, a delay, a length, a reference temperature, an
epoch).

A term adds to one of four places (:class:`Carrier`): the displacement [m] (an output error
of the mirror), the voltage in effect [V] (an amplifier's error: the law sees the command
plus the term), the temperature the law is evaluated at [degC] (a temperature the sensors
miss) or the measurement [m] (a metrology error, e.g. an interferometer's periodic
nonlinearity: the mirror is right and only its reading is off, so the calibration explains
it and the feedforward never undoes it). The calibration fits a drive or temperature term
through the model's sensitivity to that input, so the coefficient keeps the physical unit of
the place it adds to.

Compensation: ``compensation.discovered_<k>_*`` for up to :data:`SLOTS` terms (coefficient
0 = slot unused). A displacement term whose every factor is known before the command is
computed (:attr:`Factor.compensable`: functions of the set point, the temperatures and
their rates, the time, the drive's past, the grid position) is subtracted from the set
point; a temperature term of such factors moves the temperature the law is inverted at; a
drive term may also depend on the present command (V, its rate, the neighbours' commands):
the command is then solved numerically from the voltage the law asks for (fixed-point steps
per actuator, with the rate taken on the law's voltages; where they do not settle, the
first step's command goes out, counted). A displacement term of the present command is
reported but never written. A creep term (factor 20, alone on the displacement) is linear
in the displacement the law is asked for, so that displacement is solved in closed form
(:func:`creep_step`). A drive term of a slew-rate limit (factor 19, the command through a
rate limiter minus the command, coefficient 1) is written for the model (the law is fitted
to the voltage the amplifier really gave) and never undone: within the limit there is
nothing to undo, beyond it no command makes the amplifier faster.
"""

from __future__ import annotations

import enum
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
    Factor(5, "t", "s", "epoch [s]", "output", False,
           "the time since the start: a slow drift of the stand or the metrology (not "
           "compensated: a record's trend says nothing of the hours after it)"),
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
    Factor(15, "|dV/dt|", "V/s", "limit [V/s]", "drive", False,
           "the magnitude of the command's rate, up to a limit (none at 0): the amplifier's "
           "output current (a gain that droops with it, up to a current limit)"),
    Factor(16, "rim depth", "", "", "output", True,
           "the distance from the grid's rim (0 on the rim, 1 deepest): a profile from the "
           "mount inwards (heat or stress reaching the centre late)"),
    Factor(17, "x", "", "", "output", True,
           "the position along the grid's rows (-1 .. 1): a gradient across the grid from one "
           "side"),
    Factor(18, "y", "", "", "output", True,
           "the position along the grid's columns (-1 .. 1): a gradient across the grid from one "
           "side"),
    Factor(19, "RL(V)-V", "V", "limit [V/s]", "drive", False,
           "the command through a rate limiter minus the command: an amplifier's slew-rate "
           "limit (its output follows the command at most this fast)"),
    Factor(20, "creep(z)", "m", "shortest time constant [s]", "output", True,
           "low-passes of the modelled displacement minus it, one per decade of time: "
           "logarithmic creep of the actuator's strain after each change"),
)
BY_CODE: Final[dict[int, Factor]] = {f.code: f for f in FACTORS}
#: Terms the parameters file can carry.
SLOTS: Final = 3
#: Factors of the present command (a drive term's inverse varies them).
PRESENT_COMMAND: Final = frozenset({1, 2, 7, 15})
#: Factors of the modelled displacement (unknown where the law's temperature or drive is solved).
OF_DISPLACEMENT: Final = frozenset({6, 13, 14})
#: Factors of a limit no command beats (see :attr:`Term.compensable`).
LIMITS: Final = frozenset({19})
#: The creep factor: low-passes of the modelled displacement z minus z, summed; their time
#: constants are the shortest x 1, 10, 100, ... over ``CREEP_DECADES`` decades (a Prony
#: series of equal steps per decade, the usual form of a piezo's logarithmic creep
#: z (1 + gamma log10(t / t0))). Each low-pass holds z linearly between commands (first-order
#: hold, as the calibration's filters).
CREEP: Final = 20
CREEP_DECADES: Final = 4
#: Factors fixed by an actuator's place in the grid.
POSITION: Final = frozenset({16, 17, 18})
#: A drive term's inverse: fixed-point steps, and how close [V] the command must bring the
#: voltage in effect to the one asked for (see DiscoveredCompensation.invert_drive).
FIXED_POINT_STEPS: Final = 8
SOLVE_TOLERANCE_V: Final = 1e-6


def creep_time_constants(shortest: float) -> FloatArray:
    """Return the creep factor's low-pass time constants [s] from the shortest one."""
    return np.asarray(shortest * 10.0 ** np.arange(CREEP_DECADES), np.float64)


def creep_step(step_s: float, shortest: float) -> tuple[FloatArray, FloatArray]:
    """Return the creep's low-passes' (D, c) over a step of ``step_s`` [s], each (CREEP_DECADES,).

    First-order hold: y_new = D y + (1 - c) x_new + (c - D) x_old with D = exp(-h / tau)
    and c = (1 - D) tau / h; a step of 0 moves nothing (D = c = 1).
    """
    a = max(step_s, 0.0) / creep_time_constants(shortest)
    if not a[0] > 0.0:
        return np.ones(CREEP_DECADES), np.ones(CREEP_DECADES)
    return np.exp(-a), -np.expm1(-a) / a


def rate_magnitude(rate: FloatArray, limit: float) -> FloatArray:
    """Return factor 15: |rate| up to ``limit`` (no limit when ``limit`` <= 0)."""
    magnitude = np.abs(rate)
    return np.minimum(magnitude, limit) if limit > 0 else magnitude


def rate_limited(command: FloatArray, period: float, limit: float) -> FloatArray:
    """Return ``command`` (N, ...) through a rate limiter: each sample moves at most limit x period.

    The limiter starts on the first sample (factor 19 is this minus the command). A Python
    loop over the samples, vectorised over the rest; the calibration runs a compiled twin
    on long records (es_calibration.model.rate_limit_loop, the same numbers).
    """
    x = np.asarray(command, np.float64)
    out = np.empty_like(x)
    if x.shape[0] == 0:
        return out
    step = limit * period
    state = x[0].copy()
    for i in range(x.shape[0]):
        state += np.clip(x[i] - state, -step, step)
        out[i] = state
    return out


class Carrier(enum.IntEnum):
    """Where a discovered term adds (its code in ``compensation.discovered_<k>_acts_on``)."""

    DISPLACEMENT = 0
    DRIVE = 1
    TEMPERATURE = 2
    MEASUREMENT = 3

    @property
    def unit(self) -> str:
        """Return the unit of what the term adds to."""
        return ("m", "V", "degC", "m")[self]

    @property
    def words(self) -> str:
        """Return what the term adds to, in words."""
        return ("the displacement", "the voltage in effect (the amplifier's output)",
                "the temperature the law sees",
                "the measurement (correct the metrology, not the mirror)")[self]


def grid_position(code: int, shape: tuple[int, int]) -> FloatArray:
    """Return a position factor (16 rim depth, 17 x, 18 y) on a grid ``shape`` (R, C).

    Raises:
        KeyError: ``code`` is not a position factor.

    """
    rows, cols = shape
    r = np.arange(rows, dtype=np.float64)[:, None]
    c = np.arange(cols, dtype=np.float64)[None, :]
    if code == 16:
        depth = np.minimum(np.minimum(r, rows - 1 - r), np.minimum(c, cols - 1 - c))
        deepest = float(depth.max())
        return depth / deepest if deepest > 0 else np.zeros(shape)
    if code == 17:
        return np.broadcast_to(2.0 * c / (cols - 1) - 1.0 if cols > 1 else 0.0 * c, shape).copy()
    if code == 18:
        return np.broadcast_to(2.0 * r / (rows - 1) - 1.0 if rows > 1 else 0.0 * r, shape).copy()
    raise KeyError(f"no position factor with code {code}")


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
    """A coefficient times one or two factors (each (code, parameter)); ``b`` is None alone.

    ``acts_on``: where the product adds (the coefficient's unit is that place's per the
    factors').
    """

    coefficient: float
    a: tuple[int, float]
    b: tuple[int, float] | None = None
    acts_on: Carrier = Carrier.DISPLACEMENT

    @property
    def factors(self) -> tuple[tuple[int, float], ...]:
        """Return the term's (code, parameter) factors."""
        return (self.a,) if self.b is None else (self.a, self.b)

    @property
    def compensable(self) -> bool:
        """Whether the feedforward can undo the term (see the module docstring)."""
        codes = {c for c, _ in self.factors}
        if self.acts_on is Carrier.MEASUREMENT:  # the mirror is right: nothing to undo
            return False
        if codes & LIMITS:  # within the limit nothing to undo, beyond it no command is faster
            return False
        if CREEP in codes:  # solved in closed form from the set point (see the module)
            return self.acts_on is Carrier.DISPLACEMENT and self.b is None
        if self.acts_on is Carrier.DRIVE:
            return not codes & OF_DISPLACEMENT
        if self.acts_on is Carrier.TEMPERATURE and codes & OF_DISPLACEMENT:
            return False
        return all(BY_CODE[c].compensable for c in codes)


def expression(factors: Sequence[tuple[int, float]]) -> str:
    """Return the factors as text, e.g. ``LP(V^2)[tau=0.8 s] * T[ref=45 degC]``."""
    parts = []
    for code, value in factors:
        f = BY_CODE[code]
        name = f.parameter.split(" [")[0]
        parts.append(f"{f.key}[{name}={value:.4g}]" if f.parameter else f.key)
    return " * ".join(parts)


def unit(factors: Sequence[tuple[int, float]], acts_on: Carrier = Carrier.DISPLACEMENT) -> str:
    """Return the coefficient's unit: ``acts_on``'s unit per the factors' units."""
    units = [BY_CODE[c].unit for c, _ in factors if BY_CODE[c].unit]
    return acts_on.unit if not units else f"{acts_on.unit}/(" + " ".join(units) + ")"


def _slot_parameters(k: int) -> tuple[Parameter, ...]:
    codes = float(len(FACTORS))
    return (
        Parameter(f"discovered_{k}_coefficient", "", -1e6, 1e6, 0.0,
                  f"term {k}: coefficient [m, V or degC (acts_on) per the factors' units] "
                  "(0 = unused)"),
        Parameter(f"discovered_{k}_factor_a", "", 0.0, codes, 0.0,
                  f"term {k}: first factor's code (es_physics.effects.discovered.FACTORS)"),
        Parameter(f"discovered_{k}_parameter_a", "", -1e12, 1e12, 0.0,
                  f"term {k}: first factor's parameter"),
        Parameter(f"discovered_{k}_factor_b", "", 0.0, codes, 0.0,
                  f"term {k}: second factor's code (0 = none)"),
        Parameter(f"discovered_{k}_parameter_b", "", -1e12, 1e12, 0.0,
                  f"term {k}: second factor's parameter"),
        Parameter(f"discovered_{k}_acts_on", "", 0.0, float(max(Carrier)), 0.0,
                  f"term {k}: what it adds to: 0 the displacement [m], 1 the drive [V], "
                  "2 the law's temperature [degC] (3, the measurement, is never written)"),
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
        carrier = round(values.get(f"discovered_{k}_acts_on", 0.0))
        if carrier not in tuple(Carrier):
            continue
        terms.append(Term(coefficient, (code_a, float(values[f"discovered_{k}_parameter_a"])), b,
                          Carrier(carrier)))
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
            f"discovered_{k}_acts_on": float(term.acts_on),
        })
    return values


class DiscoveredCompensation(Compensator):
    """The discovered terms undone in the feedforward (vectorised over the grid).

    Displacement terms are subtracted from the set point (:meth:`setpoint`), temperature
    terms added to the temperature the law is inverted at (:meth:`law_temperature`), drive
    terms solved from the voltage the law asks for (:meth:`invert_drive`). State: the
    temperature rate from consecutive estimates (:meth:`measured_temperature`), one low-pass
    per (signal, time constant) and the recent commands (for delayed ones and the command's
    rate), advanced in :meth:`commit` with the command held between commands.

    Attributes:
        unconverged: commands (actuator x command) whose drive terms could not be solved
            and went out uncompensated (the drive terms' inverse never reaches an actuator
            unchecked).

    """

    def __init__(self, terms: Sequence[Term], shape: tuple[int, int],
                 last_voltage: FloatArray | None = None) -> None:
        compensable = [t for t in terms if t.compensable]
        self.terms = compensable
        self._creep_terms = [t for t in compensable if t.a[0] == CREEP]
        self._by_carrier = {c: [t for t in compensable if t.acts_on is c
                                and t not in self._creep_terms] for c in Carrier}
        self.reshapes_drive = bool(self._by_carrier[Carrier.DRIVE])
        self.shape = shape
        start = np.zeros(shape) if last_voltage is None else np.asarray(last_voltage, np.float64)
        self._lowpass: dict[tuple[int, float], FloatArray] = {
            (c, p): (start**2 if c == 11 else start.copy())
            for t in self.terms for c, p in t.factors if c in (10, 11)
        }
        self._position = {c: grid_position(c, shape) for c in POSITION}
        delays = [p for t in self.terms for c, p in t.factors if c == 12]
        self._max_delay = max(delays, default=0.0)
        self._sent: deque[tuple[float, FloatArray]] = deque()
        self._last = start
        self._last_t: float | None = None
        self._temperature: tuple[float, FloatArray] | None = None
        self._rate = np.zeros(shape)
        self._law: tuple[float, FloatArray] | None = None  # the last voltage the law asked for
        # creep: the last displacement the law was asked for and when, the low-passes then
        # (CREEP_DECADES, R, C) per term; and this command's, kept by commit()
        self._creep: tuple[float, FloatArray, list[FloatArray]] | None = None
        self._creep_asked: tuple[float, FloatArray, list[FloatArray]] | None = None
        self.unconverged = 0

    def carry_over(self, previous: DiscoveredCompensation) -> None:
        """Take ``previous``'s state (copied: it stays usable) where the terms share it."""
        for key in self._lowpass.keys() & previous._lowpass.keys():
            self._lowpass[key] = previous._lowpass[key].copy()
        self._sent = deque(previous._sent)
        self._last, self._last_t = previous._last.copy(), previous._last_t
        self._temperature, self._rate = previous._temperature, previous._rate.copy()
        self._law = previous._law
        if previous._creep is not None and [t.a for t in previous._creep_terms] == [
                t.a for t in self._creep_terms]:
            self._creep = previous._creep
        self.unconverged = previous.unconverged

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

    def _command_rate(self, v: FloatArray, t: float) -> FloatArray:
        """Return (v - the last command) / the time since it, 0 before the first command."""
        if self._last_t is None or t <= self._last_t:
            return np.zeros(self.shape)
        return np.asarray((v - self._last) / (t - self._last_t), np.float64)

    def _factor(self, code: int, parameter: float, t: float, *, z: FloatArray | None = None,
                T: FloatArray | None = None, v: FloatArray | None = None,
                rate: FloatArray | None = None) -> FloatArray | float:
        """Return one factor's value; ``z``, ``T``, ``v``: set point, temperature, command.

        ``rate``: the command's rate to use (default: from ``v`` and the last command).
        """
        if code in POSITION:
            return self._position[code]
        if code in PRESENT_COMMAND:
            assert v is not None  # Term.compensable keeps these to drive terms
            if code == 1:
                return v
            if code == 7:
                return neighbour_mean(v)
            if rate is None:
                rate = self._command_rate(v, t)
            return rate if code == 2 else rate_magnitude(rate, parameter)
        if code in OF_DISPLACEMENT:
            assert z is not None  # Term.compensable keeps these to displacement terms
            if code == 6:
                return z
            phase = 2.0 * np.pi * z / parameter
            return np.sin(phase) if code == 13 else np.cos(phase)
        if code in (3, 8):
            assert T is not None
            return T - parameter if code == 3 else neighbour_mean(T) - T
        if code == 4:
            return self._rate
        if code == 5:
            return t - parameter
        if code == 9:
            return neighbour_mean(self._rate)
        if code in (10, 11):
            return self._lowpass_at((code, parameter), t)
        return self._delayed(parameter, t)  # code 12

    def _sum(self, carrier: Carrier, t: float, **signals: FloatArray | None) -> FloatArray:
        """Return the sum of ``carrier``'s terms (a non-finite value counts as 0).

        The signals are grids (R, C), or stacks of them (K, R, C) for K candidates at once.
        """
        total = np.zeros(self.shape)
        for term in self._by_carrier[carrier]:
            value: FloatArray | float = term.coefficient
            for code, parameter in term.factors:
                value = value * self._factor(code, parameter, t, **signals)
            total = total + value
        return np.asarray(np.where(np.isfinite(total), total, 0.0), np.float64)

    def law_temperature(self, T: FloatArray, t: float) -> FloatArray:
        """Return ``T`` plus the temperature terms (the temperature the actuator really has)."""
        if not self._by_carrier[Carrier.TEMPERATURE]:
            return T
        return np.asarray(T + self._sum(Carrier.TEMPERATURE, t, T=T), np.float64)

    def setpoint(self, z: FloatArray, T: FloatArray, t: float) -> FloatArray:
        """Return z minus the displacement terms, the creep's solved (see the module)."""
        if self._by_carrier[Carrier.DISPLACEMENT]:
            z = np.asarray(z - self._sum(Carrier.DISPLACEMENT, t, z=z, T=T), np.float64)
        return self._without_creep(z, t) if self._creep_terms else z

    def _without_creep(self, z: FloatArray, t: float) -> FloatArray:
        """Return the displacement x the law must give so that x + the creep terms is ``z``.

        Each term is gamma sum_k (LP_k(x) - x) with LP_k(x) = D y_k + (1 - c) x + (c - D) x_old
        (:func:`creep_step`), so x (1 - sum gamma sum_k c_k) = z - sum gamma sum_k (D y_k +
        (c - D) x_old). The low-passes start settled at the first set point; where the
        denominator is not positive (a creep the command cannot undo) z goes as it is.
        """
        z = np.asarray(z, np.float64)
        if self._creep is None:
            self._creep_asked = (t, z.copy(), [np.broadcast_to(z, (CREEP_DECADES, *z.shape))
                                               .copy() for _ in self._creep_terms])
            return z
        last_t, old, states = self._creep
        known, slope, steps = np.zeros_like(z), 1.0, []
        for term, y in zip(self._creep_terms, states, strict=True):
            D, c = creep_step(t - last_t, term.a[1])
            shape = (-1, *(1,) * z.ndim)
            known = known + term.coefficient * np.sum(D.reshape(shape) * y
                                                      + (c - D).reshape(shape) * old, axis=0)
            slope -= term.coefficient * float(np.sum(c))
            steps.append((D.reshape(shape), c.reshape(shape)))
        x = (z - known) / slope if slope > 0.0 else z
        x = np.asarray(np.where(np.isfinite(x), x, z), np.float64)
        self._creep_asked = (t, x, [D * y + (1.0 - c) * x + (c - D) * old
                                    for (D, c), y in zip(steps, states, strict=True)])
        return x

    def invert_drive(self, voltage: FloatArray, t: float) -> FloatArray:
        """Return the command v with v + drive terms(v) = ``voltage``, per actuator.

        The terms' rate factors are taken on the voltage the law asks for (its change since
        the last command): that is the rate the amplifier's output should have. Solving
        against the command's own rate instead makes each command push against the last
        one's term (a per-sample loop of gain c V / dt, near 1 for a strong droop): on the
        independent stand that amplified the slightest mismatch of the rate's definition
        (closed-loop error 2.2 x that of no compensation). The rest of the terms (V, the
        neighbours' commands) are solved by fixed-point steps, at most ``FIXED_POINT_STEPS``
        (fewer once every actuator settled within ``SOLVE_TOLERANCE_V``); where they do not
        settle (a term of gain near or beyond 1), the first step's command goes out, counted
        in :attr:`unconverged`.
        """
        if not self.reshapes_drive:
            return voltage
        T = self._temperature[1] if self._temperature is not None else None
        target = np.asarray(voltage, np.float64)
        if self._law is None or t <= self._law[0]:
            rate = np.zeros(self.shape)
        else:
            rate = (target - self._law[1]) / (t - self._law[0])
        self._law = (t, target.copy())
        first = target - self._sum(Carrier.DRIVE, t, v=target, T=T, rate=rate)
        v = first
        for step in range(FIXED_POINT_STEPS):
            following = target - self._sum(Carrier.DRIVE, t, v=v, T=T, rate=rate)
            miss = v - following  # v + terms(v) - voltage: how far v is from the solution
            # a step's change is the last iterate's miss: stop once every actuator settled
            if step == FIXED_POINT_STEPS - 1 or np.all(np.abs(miss) <= SOLVE_TOLERANCE_V):
                break
            v = following
        bad = ~(np.abs(miss) <= SOLVE_TOLERANCE_V)
        if bad.any():
            self.unconverged += int(bad.sum())
            v = np.where(bad, first, v)
        return np.asarray(np.where(np.isfinite(v), v, target), np.float64)

    def counters(self) -> dict[str, int]:
        """Return the actuator commands whose drive terms were out of reach."""
        return {"drive_out_of_reach": self.unconverged} if self.reshapes_drive else {}

    def commit(self, sent: FloatArray, drive: FloatArray, t: float) -> FloatArray:
        """Advance the low-passes over the held command and keep ``sent``.

        Returns ``drive`` plus the drive terms of ``sent`` (the voltage in effect).
        """
        out = drive
        if self.reshapes_drive:
            T = self._temperature[1] if self._temperature is not None else None
            out = np.asarray(drive + self._sum(Carrier.DRIVE, t, v=np.asarray(sent), T=T),
                             np.float64)
        for key in self._lowpass:
            self._lowpass[key] = self._lowpass_at(key, t)
        if self._creep_asked is not None:
            self._creep, self._creep_asked = self._creep_asked, None
        self._last = np.asarray(sent, np.float64).copy()
        self._last_t = t
        if self._max_delay > 0.0:
            self._sent.append((t, self._last))
            while len(self._sent) > 2 and self._sent[1][0] <= t - self._max_delay - 1e-9:
                self._sent.popleft()
        return out


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
