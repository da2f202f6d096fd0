"""Scenario reference signals: displacement set points and test-stand voltage excitations.

Set point per actuator: z_ref(t) = offset + sum_i a_i Z_i(x, y) + A sin(2 pi f t + phi) [m],
Z_i low-order Zernike-like shapes on the grid's normalised coordinates (x across columns, y
across rows, each in [-1, 1]) scaled to a peak |Z_i| of 1 over the grid, so ``a_i`` is the
term's peak amplitude in metres. Frequencies are never time-scaled (the actuator is
quasi-static; only the slow thermal parts of a scenario are shortened).

Excitation (characterisation runs, no feedforward): the voltage program of a signal
generator, V(t) = offset_v + A_v sin(2 pi f t + phi_i), stepping through every combination of
``offsets_v`` x ``amplitudes_v`` x ``frequencies_hz`` for ``level_s`` each, cyclically, with a
seeded random phase phi_i per actuator (neighbours uncorrelated) and saturated at the
amplifier limit.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np

from es_common.arrays import FloatArray
from es_sim_plant.errors import ScenarioError
from es_sim_plant.thermal import normalised_coordinates

_ZERNIKE: Final[dict[str, Callable[[FloatArray, FloatArray, FloatArray], FloatArray]]] = {
    "tip": lambda x, y, r2: x,
    "tilt": lambda x, y, r2: y,
    "defocus": lambda x, y, r2: 2.0 * r2 - 1.0,
    "astig_0": lambda x, y, r2: x * x - y * y,
    "astig_45": lambda x, y, r2: 2.0 * x * y,
    "coma_x": lambda x, y, r2: (3.0 * r2 - 2.0) * x,
    "coma_y": lambda x, y, r2: (3.0 * r2 - 2.0) * y,
    "trefoil_x": lambda x, y, r2: x**3 - 3.0 * x * y * y,
    "trefoil_y": lambda x, y, r2: 3.0 * x * x * y - y**3,
    "spherical": lambda x, y, r2: 6.0 * r2 * r2 - 6.0 * r2 + 1.0,
}
#: Names of the shape terms a scenario may use.
SHAPE_TERMS: Final = tuple(_ZERNIKE)


def shape_term(name: str, shape: tuple[int, int]) -> FloatArray:
    """Return the Zernike-like term ``name`` on the grid, scaled to peak |value| 1 (or all 0)."""
    y, x = normalised_coordinates(shape)
    values = _ZERNIKE[name](x, y, 0.5 * (x * x + y * y))
    peak = float(np.max(np.abs(values)))
    return np.asarray(values / peak if peak > 0.0 else np.zeros(shape), np.float64)


@dataclass(frozen=True)
class SetpointSpec:
    """Set-point generator parameters (metres, hertz, degrees)."""

    offset: float = 0.0
    shape: dict[str, float] = field(default_factory=dict)
    sine_amplitude: float = 0.0
    sine_frequency: float = 1.0
    sine_phase_deg: float = 0.0

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> SetpointSpec:
        """Build from a scenario's ``setpoint`` mapping; raise ``ScenarioError`` on bad entries.

        Raises:
            ScenarioError: bad keys, types or values (the message says which).

        """
        data = dict(data or {})
        sine = dict(data.pop("sine", None) or {})
        shape = dict(data.pop("shape", None) or {})
        offset = data.pop("offset", 0.0)
        if data:
            raise ScenarioError(
                f"setpoint: unknown key(s) {sorted(data)}; known offset, shape, sine"
            )
        unknown_terms = set(shape) - set(SHAPE_TERMS)
        if unknown_terms:
            raise ScenarioError(
                f"setpoint.shape: unknown term(s) {sorted(unknown_terms)}; "
                f"known {list(SHAPE_TERMS)}"
            )
        bad = set(sine) - {"amplitude", "frequency", "phase_deg"}
        if bad:
            raise ScenarioError(f"setpoint.sine: unknown key(s) {sorted(bad)}")
        try:
            spec = cls(
                offset=float(offset),
                shape={k: float(v) for k, v in shape.items()},
                sine_amplitude=float(sine.get("amplitude", 0.0)),
                sine_frequency=float(sine.get("frequency", 1.0)),
                sine_phase_deg=float(sine.get("phase_deg", 0.0)),
            )
        except (TypeError, ValueError):
            raise ScenarioError("setpoint: values must be numbers") from None
        if spec.sine_frequency < 0.0 or spec.sine_amplitude < 0.0:
            raise ScenarioError("setpoint.sine: amplitude and frequency must be >= 0")
        return spec


class SetpointGenerator:
    """Evaluates a :class:`SetpointSpec` on one grid; :meth:`at` costs one sine and one add."""

    def __init__(self, spec: SetpointSpec, shape: tuple[int, int]) -> None:
        """Evaluate ``spec`` on a grid of ``shape`` (rows, cols).

        Raises:
            ScenarioError: bad keys, types or values (the message says which).

        """
        self.spec = spec
        static = np.full(shape, spec.offset)
        for name, amplitude in spec.shape.items():
            static = static + amplitude * shape_term(name, shape)
        #: The static part of the set point (R, C) [m].
        self.static = static
        if float(np.min(static)) - spec.sine_amplitude < 0.0:
            raise ScenarioError(
                "setpoint reaches below 0 m (an electrostrictive actuator only expands): "
                f"static minimum {np.min(static):.3g} m, sine amplitude {spec.sine_amplitude:.3g} m"
            )
        self._omega = 2.0 * np.pi * spec.sine_frequency
        self._phase = np.deg2rad(spec.sine_phase_deg)

    def at(self, t: float) -> FloatArray:
        """Return the set point (R, C) [m] at time ``t`` [s]."""
        ac = self.spec.sine_amplitude * np.sin(self._omega * t + self._phase)
        return np.asarray(self.static + ac, np.float64)


@dataclass(frozen=True)
class Excitation:
    """Test-stand voltage program (see the module docstring); volts, hertz, seconds."""

    offsets_v: tuple[float, ...] = (0.0, 100.0)
    amplitudes_v: tuple[float, ...] = (50.0, 150.0, 250.0)
    frequencies_hz: tuple[float, ...] = (1.0, 3.0)
    level_s: float = 2.0
    phase_spread: bool = True

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Excitation:
        """Build from a scenario's ``excitation`` mapping; raise ``ScenarioError`` on bad entries.

        Raises:
            ScenarioError: bad keys, types or values (the message says which).

        """
        data = dict(data)
        known = {"offsets_v", "amplitudes_v", "frequencies_hz", "level_s", "phase_spread"}
        bad = set(data) - known
        if bad:
            raise ScenarioError(f"excitation: unknown key(s) {sorted(bad)}; known {sorted(known)}")
        default = cls()
        try:
            exc = cls(
                offsets_v=tuple(float(v) for v in data.get("offsets_v", default.offsets_v)),
                amplitudes_v=tuple(
                    float(v) for v in data.get("amplitudes_v", default.amplitudes_v)
                ),
                frequencies_hz=tuple(
                    float(v) for v in data.get("frequencies_hz", default.frequencies_hz)
                ),
                level_s=float(data.get("level_s", default.level_s)),
                phase_spread=bool(data.get("phase_spread", default.phase_spread)),
            )
        except (TypeError, ValueError):
            raise ScenarioError(
                "excitation: lists of numbers and a number level_s expected"
            ) from None
        if not (exc.offsets_v and exc.amplitudes_v and exc.frequencies_hz) or exc.level_s <= 0:
            raise ScenarioError(
                "excitation: non-empty offsets, amplitudes, frequencies; level_s > 0"
            )
        return exc


class ExcitationGenerator:
    """Evaluates an :class:`Excitation` on one grid (phases drawn once from ``rng``)."""

    def __init__(
        self, spec: Excitation, shape: tuple[int, int], v_limit: float, rng: np.random.Generator
    ) -> None:
        self.spec = spec
        self.v_limit = v_limit
        self.levels = list(
            itertools.product(spec.offsets_v, spec.amplitudes_v, spec.frequencies_hz)
        )
        phases = rng.uniform(0.0, 2.0 * np.pi, shape)
        self.phases = phases if spec.phase_spread else np.zeros(shape)

    def at(self, t: float) -> FloatArray:
        """Return the commanded voltages (R, C) [V] at time ``t``."""
        offset, amplitude, frequency = self.levels[int(t // self.spec.level_s) % len(self.levels)]
        v = offset + amplitude * np.sin(2.0 * np.pi * frequency * t + self.phases)
        return np.asarray(np.clip(v, -self.v_limit, self.v_limit), np.float64)
