"""Frequency dispersion of the permittivity: the gain falls as the drive gets faster.

A first-order (Debye-like) relaxation: part ``r`` of the polarisation follows the drive only
through a low-pass of corner ``f_c``, so the voltage in effect is

    V_eff = (1 - r) V + r s,    ds/dt = 2 pi f_c (V - s),

i.e. V_eff = V - r highpass_(f_c)(V): unity gain at DC, 1 - r far above f_c. Discretised
for a drive held over steps of dt (exact for the held drive): the output of a step uses
the state at its start, then s <- s + (1 - exp(-2 pi f_c dt)) (V - s)
(:func:`relaxation_output`, :func:`relaxation_advance`). The output at a time h into a
held step is V - r D (V - s), D = exp(-2 pi f_c h): exactly invertible for r < 1,
V = (V_eff - r D s) / (1 - r D) (:func:`relaxation_inverse`).

Plant: the filter acts on the drive after any hysteresis, at the plant's internal rate.
Feedforward: its inverse on the voltage the law needs at the end of the coming command
interval (taken as long as the last one), where the displacement is observed
(``compensation.dispersion_fraction``, ``compensation.dispersion_corner_hz``).

Calibration (role ``RELAXATION``): V_eff = V - r (V - LP_(f_c)(V)) on the command in effect,
the low-pass for a command varying linearly between its samples; unknowns r and log f_c,
reported as ``fraction`` and ``corner_hz`` [Hz]. With a hysteresis in the same model the
two act side by side on the command (their product, of order r times the weights, is left
out).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import ClassVar, Final

import numpy as np

from es_physics.effects.base import (
    Effect,
    FittedEffect,
    FloatArray,
    Parameter,
    Role,
    filter_undetermined,
)
from es_physics.effects.identifiable import Identifiable
from es_physics.effects.stages import Compensator, PlantContext, PlantStage, StepState
from es_physics.errors import EffectParameterError

#: Highest relaxation fraction the compensation accepts (its inverse gains 1 / (1 - r)).
MAX_FRACTION = 0.9
#: Starting fraction of the calibration's fit (so the corner has a gradient).
START_FRACTION: Final = 0.05
#: Corner frequencies the calibration starts from [Hz].
START_CORNERS_HZ: Final = (3.0, 15.0)
#: Corner frequencies the calibration accepts [Hz].
CORNER_RANGE_HZ: Final = (1e-3, 1e5)


def relaxation_decay(corner_hz: float, dt: float) -> float:
    """Return exp(-2 pi f_c dt): how much of the state's gap to the drive survives a step.

    Args:
        corner_hz: relaxation corner frequency f_c [Hz] (> 0).
        dt: step length [s] (>= 0).

    Raises:
        EffectParameterError: f_c not positive or dt negative (or either not finite).

    """
    if not (np.isfinite(corner_hz) and corner_hz > 0.0):
        raise EffectParameterError(f"corner frequency {corner_hz!r} Hz must be > 0")
    if not (np.isfinite(dt) and dt >= 0.0):
        raise EffectParameterError(f"step {dt!r} s must be >= 0")
    return float(np.exp(-2.0 * np.pi * corner_hz * dt))


def relaxation_output(
    voltage: FloatArray, state: FloatArray, fraction: float, decay: float = 1.0
) -> FloatArray:
    """Return V_eff = V - r D (V - s) for the drive ``voltage`` held from the state ``state``.

    ``decay`` D = :func:`relaxation_decay` of the time since the drive started: D = 1 (the
    default) gives the output as the drive starts, (1 - r) V + r s [V].
    """
    return np.asarray(voltage - fraction * decay * (voltage - state), np.float64)


def relaxation_advance(voltage: FloatArray, state: FloatArray, decay: float) -> FloatArray:
    """Return the state after a step of held drive: V + (s - V) decay [V]."""
    return np.asarray(voltage + (state - voltage) * decay, np.float64)


def relaxation_inverse(
    v_eff: FloatArray, state: FloatArray, fraction: float, decay: float = 1.0
) -> FloatArray:
    """Return the drive V that makes :func:`relaxation_output` give ``v_eff`` [V].

    V = (V_eff - r D s) / (1 - r D), D = ``decay`` in [0, 1].

    Raises:
        EffectParameterError: ``fraction`` not in [0, 1) (the inverse does not exist) or ``decay``
            not in [0, 1].

    """
    if not 0.0 <= fraction < 1.0:
        raise EffectParameterError(f"relaxation fraction {fraction!r} must be in [0, 1)")
    if not 0.0 <= decay <= 1.0:
        raise EffectParameterError(f"relaxation decay {decay!r} must be in [0, 1]")
    rd = fraction * decay
    return np.asarray((v_eff - rd * state) / (1.0 - rd), np.float64)


class RelaxationInverse(Compensator):
    """Exact inverse of the drive's first-order relaxation (effect ``frequency_dispersion``).

    V_out = V - r D (V - s) at the end of a command interval h (D = exp(-2 pi f_c h), h taken
    as the last interval), ds/dt = 2 pi f_c (V - s) with the drive held between commands;
    per-actuator states s [V] (``shape``), advanced with the drive actually sent.
    """

    reshapes_drive = True

    def __init__(self, fraction: float, corner_hz: float, shape: tuple[int, ...]) -> None:
        self.fraction = fraction
        self.corner_hz = corner_hz
        self.state: FloatArray | None = None
        self.shape = shape
        self._last: tuple[FloatArray, float] | None = None
        self._interval = 0.0

    @property
    def active(self) -> bool:
        """Whether the relaxation does anything."""
        return self.fraction > 0.0

    def retuned(self, fraction: float, corner_hz: float) -> RelaxationInverse:
        """Return a copy with new parameters and this one's state (this one is unchanged)."""
        other = RelaxationInverse(fraction, corner_hz, self.shape)
        other.state, other._last, other._interval = self.state, self._last, self._interval
        return other

    def _state_at(self, t: float) -> FloatArray | None:
        """Return the state at time ``t`` [s]: the last drive held since it was sent."""
        if self._last is None or self.state is None:
            return None
        drive, sent = self._last
        if t <= sent:
            return self.state
        return relaxation_advance(drive, self.state, relaxation_decay(self.corner_hz, t - sent))

    def invert(self, v_out: FloatArray, t: float) -> FloatArray:
        """Return the drive sent at ``t`` [s] that makes the output ``v_out`` [V] an interval on.

        Before any drive was sent the state starts at ``v_out`` (bumpless: drive = v_out).
        """
        state = self._state_at(t)
        if not self.active or state is None:
            return v_out
        decay = relaxation_decay(self.corner_hz, self._interval)
        return relaxation_inverse(v_out, state, self.fraction, decay)

    def apply(self, drive: FloatArray, t: float) -> None:
        """Advance the state to ``t`` [s] and hold ``drive`` [V] (the voltage sent) from then."""
        state = self._state_at(t)
        if self._last is not None and t > self._last[1]:
            self._interval = t - self._last[1]
        self.state = np.array(drive, np.float64) if state is None else state
        self._last = (np.array(drive, np.float64), t)

    def invert_drive(self, voltage: FloatArray, t: float) -> FloatArray:
        """Return the drive through the relaxation's inverse (see :meth:`invert`)."""
        return self.invert(voltage, t)

    def commit(self, sent: FloatArray, drive: FloatArray, t: float) -> FloatArray:
        """Advance the state with ``drive`` (the relaxation's input) and pass it on."""
        self.apply(drive, t)
        return drive


class RelaxationStage(PlantStage):
    """The plant's relaxation of the drive, at every internal step."""

    every_substep = True

    def __init__(self, fraction: float, corner_hz: float, context: PlantContext) -> None:
        self.fraction = fraction
        self._decay = relaxation_decay(corner_hz, context.dt / context.substeps)
        #: Relaxation state of the drive [V], (R, C).
        self.state = np.zeros(context.shape)

    def drive(self, voltage: FloatArray, step: StepState) -> FloatArray:
        """Return the relaxed drive at every internal step (m, R, C) [V]."""
        V = np.array(np.broadcast_to(voltage, step.T.shape))
        for i in range(V.shape[0]):  # over time; vectorised over the grid
            drive = V[i].copy()
            V[i] = relaxation_output(drive, self.state, self.fraction)
            self.state = relaxation_advance(drive, self.state, self._decay)
        return V


class FrequencyDispersion(Effect):
    """First-order relaxation of the actuator's gain with drive frequency."""

    name: ClassVar[str] = "frequency_dispersion"
    summary: ClassVar[str] = "permittivity relaxes: the gain falls by r above a corner f_c"
    role: ClassVar[Role] = Role.RELAXATION
    simulated: ClassVar[bool] = True
    fit_parameters: ClassVar[tuple[str, ...]] = ("fraction", "log_corner_hz")
    plant: ClassVar[tuple[Parameter, ...]] = (
        Parameter("fraction", "", 0.0, 1.0, 0.1, "relaxing fraction r of the gain", high_open=True),
        Parameter("corner_hz", "Hz", 0.0, 1e6, 20.0, "relaxation corner f_c", low_open=True),
    )
    identifiable: ClassVar[Mapping[str, Identifiable]] = {
        "corner_hz": Identifiable.CORNER_FREQUENCY
    }
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "dispersion_fraction", "", 0.0, MAX_FRACTION, 0.0, "relaxing fraction r (0 = off)"
        ),
        Parameter("dispersion_corner_hz", "Hz", 1e-6, 1e6, 20.0, "relaxation corner f_c"),
    )

    def starts(self, duration_s: float) -> list[dict[str, float]]:
        """Start from a small fraction at a low and a high corner."""
        return [
            {"fraction": START_FRACTION, "log_corner_hz": math.log(f)} for f in START_CORNERS_HZ
        ]

    def drive_signal(
        self, command: FloatArray, period: float, shape: Sequence[float] = ()
    ) -> FloatArray:
        """Return the command itself (N, A) [V]: its low-pass is the relaxing part's state."""
        return np.asarray(command, np.float64)

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return ``fraction`` and ``corner_hz`` [Hz]."""
        return {
            "fraction": float(fit.values["fraction"]),
            "corner_hz": float(np.exp(fit.values["log_corner_hz"])),
        }

    def uncertainties(self, fit: FittedEffect) -> dict[str, float]:
        """Propagate the log-parameter's uncertainty to ``corner_hz``."""
        return {
            "fraction": float(fit.sigma["fraction"]),
            "corner_hz": float(np.exp(fit.values["log_corner_hz"]))
            * float(fit.sigma["log_corner_hz"]),
        }

    def problem(self, reported: dict[str, float]) -> str | None:
        """Reject a fraction outside (0, MAX_FRACTION) or a corner outside CORNER_RANGE_HZ."""
        if not 0.0 < reported["fraction"] < MAX_FRACTION:
            return f"fraction {reported['fraction']:.3g} outside (0, {MAX_FRACTION:g})"
        low, high = CORNER_RANGE_HZ
        if not low <= reported["corner_hz"] <= high:
            return f"corner_hz {reported['corner_hz']:.3g} outside [{low:g}, {high:g}]"
        return None

    def undetermined(self, fit: FittedEffect) -> str | None:
        """Reject a corner known to worse than a factor e, or a fraction to worse than 100 %."""
        return filter_undetermined(fit, "fraction", "log_corner_hz")

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Invert the reported relaxation."""
        return {
            "dispersion_fraction": reported["fraction"],
            "dispersion_corner_hz": reported["corner_hz"],
        }

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the drive's relaxation."""
        return RelaxationStage(settings["fraction"], settings["corner_hz"], context)

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the relaxation's inverse, or None when the fraction is 0."""
        fraction, corner = values["dispersion_fraction"], values["dispersion_corner_hz"]
        if fraction == 0.0:
            return None
        if isinstance(previous, RelaxationInverse):
            return previous.retuned(fraction, corner)
        return RelaxationInverse(fraction, corner, shape)
