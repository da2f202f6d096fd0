"""What an effect states about itself: its parameters, where it acts, how it is calibrated.

An effect is one class (a subclass of :class:`Effect`) in one module. The simulator, the
calibration and the feedforward never name an effect: they read these declarations through
:mod:`es_physics.effects.registry`.

- :attr:`Effect.plant`: the simulator's parameters (scenario ``effects.<name>.<param>``);
- :attr:`Effect.role`: the stage of the calibration's composite model the effect acts in;
  :attr:`Effect.fit_parameters` (shared by all actuators) and
  :attr:`Effect.local_parameters` (per actuator) are its unknowns there,
  :attr:`Effect.searched` those found by a scan instead of Gauss-Newton;
- :meth:`Effect.reported`, :meth:`Effect.uncertainties`, :meth:`Effect.problem`: the
  physical parameters calibration.json and the report give, and when they are unphysical;
  :attr:`Effect.identifiable`: the range a record can identify each one in;
- :attr:`Effect.compensation` and :meth:`Effect.compensation_values`: the feedforward's
  ``compensation.<param>`` parameters and how a calibration sets them;
- :meth:`Effect.plant_stage` and :meth:`Effect.compensator`: the stages the simulator and
  the feedforward build from the settings (:mod:`es_physics.effects.stages`).
"""

from __future__ import annotations

import enum
import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

from es_common.arrays import FloatArray
from es_physics.effects.identifiable import Identifiable
from es_physics.effects.stages import Compensator, PlantContext, PlantStage
from es_physics.errors import EffectError


class Role(enum.Enum):
    """The stage of the calibration's composite model an effect acts in.

    In model order: the actuator temperature T_a from the sensor's (``TEMPERATURE``) and its
    excess from the drive's own loss (``HEATING``: a coefficient times a first-order low-pass
    of :meth:`Effect.drive_signal`), the voltage in effect (``INPUT_SHIFT``: the command
    shifted in time; ``PLAY``: a play operator blended with the drive; ``RELAXATION``: a
    fraction of the drive's high-pass part, the drive minus a first-order low-pass of
    :meth:`Effect.drive_signal`, taken away), the law's own coefficients (``LAW``), a gain on
    the law's displacement (``GAIN``), the face sheet spreading it (``SPATIAL``), and terms
    added to the displacement (``ADDITIVE``, any number of effects). ``PLANT_ONLY`` effects
    exist in the simulator and are no calibration candidate.

    ``HEATING`` and ``RELAXATION`` effects have two shared unknowns, in this order: the
    coefficient and the log of the filter's time constant (``HEATING``: log tau [log s];
    ``RELAXATION``: log of the corner frequency f_c [log Hz], tau = 1 / (2 pi f_c)); then
    the :attr:`Effect.signal_parameters` that shape the filtered drive signal, if any.
    """

    TEMPERATURE = "temperature"
    HEATING = "heating"
    INPUT_SHIFT = "input_shift"
    PLAY = "play"
    RELAXATION = "relaxation"
    LAW = "law"
    GAIN = "gain"
    SPATIAL = "spatial"
    ADDITIVE = "additive"
    PLANT_ONLY = "plant_only"


@dataclass(frozen=True)
class Parameter:
    """One parameter of an effect: name, unit, accepted range, default.

    Attributes:
        name: parameter name (``effects.<effect>.<name>`` or ``compensation.<name>``).
        unit: SI unit (temperatures in degC), "" when dimensionless.
        low: lowest accepted value.
        high: highest accepted value.
        default: value when the setting is absent.
        doc: one line saying what it is.
        low_open: ``low`` itself is not accepted.
        high_open: ``high`` itself is not accepted.
        per_actuator: the data can support one value per actuator (else one for the grid).
        time_scaled: a slow (thermal, aging) time that a scenario's ``time_scale`` multiplies.

    """

    name: str
    unit: str
    low: float
    high: float
    default: float
    doc: str
    low_open: bool = False
    high_open: bool = False
    per_actuator: bool = False
    time_scaled: bool = False

    def accepts(self, value: float) -> bool:
        """Return whether ``value`` lies in the range (NaN never does)."""
        if not math.isfinite(value) and not (math.isinf(value) and math.isinf(self.high)):
            return False
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def range_text(self) -> str:
        """Return the range as text, e.g. ``[0, 0.125)``."""
        left = "(" if self.low_open else "["
        right = ")" if self.high_open else "]"
        return f"{left}{self.low:g}, {self.high:g}{right}"

    def check(self, value: float, prefix: str) -> None:
        """Raise :class:`EffectError` naming ``prefix.name`` when ``value`` is out of range.

        Raises:
            EffectError: the value is outside :meth:`range_text` or not a number.

        """
        if not self.accepts(value):
            raise EffectError(f"{prefix}.{self.name} = {value!r} must be in {self.range_text()}")


@dataclass(frozen=True)
class FittedEffect:
    """An effect's unknowns after a calibration fit, in the effect's own parameter names.

    Attributes:
        values: fitted shared parameters (:attr:`Effect.fit_parameters`) and scanned ones
            (:attr:`Effect.searched`).
        sigma: their 1-sigma uncertainties (scanned ones: the scan's resolution).
        local: fitted per-actuator parameters (:attr:`Effect.local_parameters`), each (A,).
        local_sigma: their 1-sigma uncertainties, each (A,).
        command_period: the data's command period [s].
        mean_temperature: mean temperature of the data [degC].

    """

    values: Mapping[str, float]
    sigma: Mapping[str, float]
    local: Mapping[str, FloatArray] = field(default_factory=dict)
    local_sigma: Mapping[str, FloatArray] = field(default_factory=dict)
    command_period: float = 0.0
    mean_temperature: float = 0.0


@dataclass(frozen=True)
class Additive:
    """An additive term's value and derivatives, each broadcasting against (A, n).

    Attributes:
        value: the term added to the displacement [m].
        columns: d value / d parameter, one per :attr:`Effect.fit_parameters` entry.
        d_temperature: d value / d T_a [m/degC] (0 when the term does not depend on it).

    """

    value: FloatArray
    columns: tuple[FloatArray, ...]
    d_temperature: FloatArray | float = 0.0


def filter_undetermined(fit: FittedEffect, coefficient: str, log_time: str) -> str | None:
    """Return why a filter effect's fit is undetermined, or None (``HEATING``/``RELAXATION``).

    The coefficient must be known to better than 100 % and the filter's log time constant
    to better than 1 (a factor e), each at 1 sigma; a parameter fitted per actuator (absent
    from ``fit.sigma``) is not checked here.
    """
    if coefficient in fit.sigma and not fit.sigma[coefficient] < abs(fit.values[coefficient]):
        return f"{coefficient} not determined (1-sigma {fit.sigma[coefficient]:.3g})"
    if log_time in fit.sigma and not fit.sigma[log_time] < 1.0:
        return f"{log_time} not determined (1-sigma {fit.sigma[log_time]:.3g})"
    return None


class Effect(ABC):
    """One effect beyond the basic hyperbolic law (see the module docstring)."""

    #: Canonical name (scenario ``effects.<name>``, calibration candidate, report).
    name: ClassVar[str]
    #: One sentence: what the effect is physically.
    summary: ClassVar[str]
    #: Stage of the calibration's model (PLANT_ONLY: not a candidate).
    role: ClassVar[Role]
    #: The simulator's parameters of the effect.
    plant: ClassVar[tuple[Parameter, ...]] = ()
    #: Whether es_sim_plant simulates the effect (an external effect may only be calibrated).
    simulated: ClassVar[bool] = False
    #: Shared unknowns of the calibration's Gauss-Newton fit.
    fit_parameters: ClassVar[tuple[str, ...]] = ()
    #: Per-actuator unknowns the effect adds to the law's coefficients.
    local_parameters: ClassVar[tuple[str, ...]] = ()
    #: Shared unknowns the calibration may fit one per actuator instead, when held-out
    #: scoring says the extra unknowns pay off (roles ``TEMPERATURE`` and ``HEATING``).
    local_options: ClassVar[tuple[str, ...]] = ()
    #: The last shared unknowns of a ``HEATING`` or ``RELAXATION`` effect, which shape its
    #: drive signal (:meth:`drive_signal`'s ``shape``, :meth:`drive_signal_slopes`).
    signal_parameters: ClassVar[tuple[str, ...]] = ()
    #: Unknowns the calibration finds by a scan (one value for the grid).
    searched: ClassVar[tuple[str, ...]] = ()
    #: The feedforward's ``compensation.<name>`` parameters the effect owns.
    compensation: ClassVar[tuple[Parameter, ...]] = ()
    #: Reported parameters (:meth:`reported`'s names) and the range a record can identify
    #: each in (:mod:`es_physics.effects.identifiable`): a fit outside it is a stand-in.
    identifiable: ClassVar[Mapping[str, Identifiable]] = {}

    @property
    def candidate(self) -> bool:
        """Whether the calibration may add the effect."""
        return self.role is not Role.PLANT_ONLY

    #: Most operators (terms of the same kind) the calibration may give the effect.
    max_order: ClassVar[int] = 1

    def fit_names(self, order: int = 1) -> tuple[str, ...]:
        """Return the shared unknowns with ``order`` operators (default: fit_parameters)."""
        return self.fit_parameters

    def searched_names(self, order: int = 1) -> tuple[str, ...]:
        """Return the scanned unknowns with ``order`` operators (default: searched)."""
        return self.searched

    def added_parameters(self, n_actuators: int, order: int = 1) -> int:
        """Return how many unknowns the effect adds to a fit of ``n_actuators`` actuators."""
        return (
            len(self.fit_names(order))
            + len(self.searched_names(order))
            + n_actuators * len(self.local_parameters)
        )

    def starts(self, duration_s: float) -> list[dict[str, float]]:
        """Return starting values of :attr:`fit_parameters` to try (data ``duration_s`` long)."""
        return [{}]

    @abstractmethod
    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return the physical parameters (plant names and units) of a fit."""

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Return 1-sigma uncertainties of :meth:`reported` (default: of the fit's values)."""
        return {k: float(v) for k, v in fit.sigma.items()}

    def problem(self, reported: dict[str, float]) -> str | None:
        """Return why reported parameters are unphysical, or None (default: plant ranges)."""
        for p in self.plant:
            if p.name in reported and not p.accepts(reported[p.name]):
                return f"{p.name} {reported[p.name]:.3g} outside {p.range_text()}"
        return None

    def undetermined(self, fit: FittedEffect) -> str | None:
        """Return why the fit leaves the effect's shared unknowns undetermined, or None.

        ``fit`` holds the shared unknowns' values and 1-sigma as fitted (the default accepts
        any). An effect the data cannot tell from another one (e.g. a time constant far
        beyond the record, where a filter becomes an integrator) is no finding.
        """
        return None

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Return the ``compensation.*`` values (no prefix) for reported parameters.

        ``start_time`` is the ROS time of the data's first sample [s].
        """
        return {}

    def drive_signal(
        self, command: FloatArray, period: float, shape: Sequence[float] = ()
    ) -> FloatArray:
        """Return the series a ``HEATING`` or ``RELAXATION`` effect's low-pass filters.

        Args:
            command: the command, time-major (N, A) [V], uniformly sampled.
            period: its sample period [s].
            shape: values of :attr:`signal_parameters` (empty: the effect's defaults).

        Returns:
            (N, A), in the unit the effect's coefficient multiplies.

        Raises:
            EffectError: the effect filters no drive signal.

        """
        raise EffectError(f"effect {self.name} filters no drive signal")

    def drive_signal_slopes(
        self, command: FloatArray, period: float, shape: Sequence[float]
    ) -> tuple[FloatArray, ...]:
        """Return d :meth:`drive_signal` / d each of :attr:`signal_parameters`, each (N, A).

        The default: an effect without signal parameters has none.
        """
        return ()

    def additive(self, g: Mapping[str, float], t: FloatArray, Ta: FloatArray) -> Additive:
        """Return the displacement term of an ``ADDITIVE`` effect and its derivatives.

        Args:
            g: current values of :attr:`fit_parameters`.
            t: seconds since the start of the data, shape (n,).
            Ta: actuator temperature minus the data's mean temperature, (A, n) [degC].

        Raises:
            EffectError: the effect is not additive.

        """
        raise EffectError(f"effect {self.name} is not an additive term")

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the simulator's stage of the effect for its :attr:`plant` settings.

        Args:
            settings: every :attr:`plant` parameter's value (SI units, time already scaled).
            context: the grid and time step the stage is built for.

        Raises:
            EffectError: the effect has no simulator model (:attr:`simulated` is False).

        """
        raise EffectError(f"effect {self.name} has no simulator model")

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the feedforward's stage for :attr:`compensation` values, or None when off.

        Args:
            values: every :attr:`compensation` parameter's value (no prefix).
            shape: the grid (R, C).
            previous: this effect's compensator of the configuration being replaced (its
                state carries over), or None.
            last_voltage: when a configuration is replaced, the command in force [V] (R, C)
                (for a bumpless start), else None.

        """
        return None
