"""The feedforward core's configuration: its modes, observer gains and one consistent set.

Pure (no rclpy). :class:`FeedforwardConfig` is what :class:`es_feedforward.feedforward.
Feedforward` is built from and what ``es_feedforward.param_file`` reads and writes; each
``reason_to_reject`` says why a set is not usable (the node refuses it with that line).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from enum import StrEnum
from typing import Final

import numpy as np

from es_feedforward.compensation import CompensationParams
from es_physics.laws import DEFAULT_V_LIMIT, CompiledLaws
from es_physics.params import ActuatorParams

__all__ = [
    "DEFAULT_REFERENCE_TEMPERATURE",
    "DEFAULT_TEMPERATURE_TIMEOUT",
    "OBSERVER_ITERATIONS_RANGE",
    "OBSERVER_TOLERANCE_RANGE",
    "OPERATING_T_STAR",
    "PLAUSIBLE_TEMPERATURE",
    "FeedforwardConfig",
    "Mode",
    "ObserverGains",
]

#: Middle of the thesis's 40-52 degC range: where "uncompensated" evaluates the model.
DEFAULT_REFERENCE_TEMPERATURE: Final = 46.0
#: T* = T - Tm band [degC] over which a configuration's laws must be positive (40-52 degC
#: for Tm = 38 degC); beyond it an element whose law is not positive is reported INVALID.
OPERATING_T_STAR: Final = (2.0, 14.0)
#: Temperatures [degC] outside this band are sensor or estimator faults, not actuator states.
PLAUSIBLE_TEMPERATURE: Final = (-50.0, 200.0)
#: Age [s] beyond which a temperature estimate is stale.
DEFAULT_TEMPERATURE_TIMEOUT: Final = 2.0
#: Most observer updates per set point (inclusive range).
OBSERVER_ITERATIONS_RANGE: Final = (1, 1000)
#: Observer convergence tolerance [V] (inclusive range; 0 runs every update).
OBSERVER_TOLERANCE_RANGE: Final = (0.0, 1.0)


class Mode(StrEnum):
    """Feedforward scheme (value of the ``mode`` parameter)."""

    INVERSE_HYPERBOLIC = "inverse_hyperbolic"
    INVERSE_QUADRATIC = "inverse_quadratic"
    LINEARIZED_DMAX = "linearized_dmax"
    OBSERVER = "observer"
    UNCOMPENSATED = "uncompensated"


@dataclass(frozen=True)
class ObserverGains:
    """PI gains of the observer loop (dimensionless: normalised by the observer's local gain).

    At most ``iterations`` loop updates run per set point (the observer has no dynamics, so
    the loop can run faster than the set points); the loop stops before an update that would
    move no actuator's integrator or command by more than ``tolerance`` [V] (that update is
    not applied). With kp + ki <= 1 no update overshoots. The default gains make each update
    a Newton step, so from the last set point's command a held set point takes no update and
    a 10 Hz full-range sine at 2 kHz three (64 x 64, bench_kernels). The default tolerance,
    0.1 mV, is below the step of a 20-bit converter over 350 V (0.33 mV) and about 2e-13 m of
    displacement at 150 nm.
    ``tolerance = 0`` stops only at an exact fixed point, so it gives the numbers of all
    ``iterations`` updates for every finite set point.
    """

    kp: float = 0.0
    ki: float = 1.0
    iterations: int = 6
    tolerance: float = 1e-4

    def reason_to_reject(self) -> str | None:
        """Return why these gains are not usable, or ``None``."""
        if not (self.kp >= 0.0 and self.ki > 0.0 and self.kp + self.ki <= 1.0):
            return f"observer gains need kp >= 0, ki > 0, kp + ki <= 1 (got {self.kp}, {self.ki})"
        low, high = OBSERVER_ITERATIONS_RANGE
        if not low <= self.iterations <= high:
            return f"observer.iterations={self.iterations} is outside [{low}, {high}]"
        low_tol, high_tol = OBSERVER_TOLERANCE_RANGE
        if not low_tol <= self.tolerance <= high_tol:
            return f"observer.tolerance={self.tolerance} V is outside [{low_tol}, {high_tol}]"
        return None


@dataclass(frozen=True)
class FeedforwardConfig:
    """Everything the feedforward core is configured with (one consistent set).

    ``params`` fields are scalars or arrays broadcasting to ``shape`` (per-actuator maps).
    """

    shape: tuple[int, int]
    params: ActuatorParams = field(default_factory=ActuatorParams)
    mode: Mode = Mode.INVERSE_HYPERBOLIC
    v_limit: float = DEFAULT_V_LIMIT
    reference_temperature: float = DEFAULT_REFERENCE_TEMPERATURE
    temperature_timeout: float = DEFAULT_TEMPERATURE_TIMEOUT
    compensation: CompensationParams = field(default_factory=CompensationParams)
    observer: ObserverGains = field(default_factory=ObserverGains)

    def reason_to_reject(self) -> str | None:
        """Return why this configuration is not usable, or ``None`` when it is."""
        rows, cols = self.shape
        if rows < 1 or cols < 1:
            return f"grid must be at least 1 x 1, got {rows} x {cols}"
        if not 0.0 < self.v_limit <= 1000.0:
            return f"v_limit={self.v_limit} is outside (0, 1000] V"
        if not np.isfinite(self.reference_temperature):
            return "reference_temperature must be finite"
        for f in fields(self.params):
            value = np.asarray(getattr(self.params, f.name))
            try:
                np.broadcast_to(value, self.shape)
            except ValueError:
                return f"law.{f.name} of shape {value.shape} does not fit the {rows} x {cols} grid"
            if not np.all(np.isfinite(value)):
                return f"law.{f.name} has non-finite values"
        if np.any(np.asarray(self.params.L) <= 0.0):
            return "law.L must be > 0"
        usable = CompiledLaws(self.params, self.shape).positive_between(*OPERATING_T_STAR)
        if not np.all(usable):
            worst = np.flatnonzero(~usable.ravel())[:5].tolist()
            return (
                f"M(T) or k(T) is not positive over Tm + {OPERATING_T_STAR} degC at "
                f"{int((~usable).sum())} actuator(s), e.g. index {worst}"
            )
        return self.compensation.reason_to_reject() or self.observer.reason_to_reject()
