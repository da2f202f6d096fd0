"""Recording faults of the test stand (issue 33) and their truth, drawn from :mod:`standgen.ranges`.

Faults belong to the recording, not to the actuator physics: a second logger's clock, a
temperature sensor that freezes, reads a constant or jumps, a cracked (weak) or dead
actuator, a displacement stream received late and in bursts. Each fault keeps its truth
(which sensor or actuator, when, how much) so that the sweep can score whether the
calibration found and named it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from itertools import pairwise
from typing import Any, Final

import numpy as np

from standgen.ranges import FAULT_FAMILIES, range_of

#: Sensor fault kinds and actuator fault kinds (the calibration's health KINDS end in these).
SENSOR_FAULTS: Final = ("frozen", "flat", "jump")
ACTUATOR_FAULTS: Final = ("weak", "dead")
#: Spacing [s] of the receive stamps of messages delivered together in a burst.
BURST_SPACING_S: Final = 2e-6


class FaultError(ValueError):
    """An unknown fault family, or a fault the recording's grid or sensors cannot show."""


@dataclass(frozen=True)
class ClockRate:
    """The displacement logger's clock runs ``ppm`` fast: its stamps are t (1 + ppm 1e-6)."""

    ppm: float


@dataclass(frozen=True)
class SensorFault:
    """Temperature sensor ``sensor`` (row-major index) fails from ``start_s`` [s].

    ``frozen``: holds its last reading before ``start_s``; ``flat``: reads ``value_degc``
    from the start (``start_s`` 0); ``jump``: its reading steps by each ``(time_s, step_degc)``
    of ``jumps`` and keeps the step (``start_s``: the first jump).
    """

    kind: str
    sensor: int
    start_s: float
    value_degc: float | None = None
    jumps: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class ActuatorFault:
    """Actuator ``index`` (row-major) moves ``fraction`` of its law (``dead``: 0)."""

    kind: str
    index: int
    fraction: float


@dataclass(frozen=True)
class ReceiveJitter:
    """Displacement messages received late, and in bursts.

    Each is delayed by an exponential draw of mean ``mean_s`` [s]; every message sampled in a
    burst window ``(start_s, length_s, late_s)`` arrives together ``late_s`` after the
    window's end. Receive order is sample order (one TCP stream).
    """

    mean_s: float
    bursts: tuple[tuple[float, float, float], ...]


@dataclass(frozen=True)
class Faults:
    """The faults of one recording (``None``: absent)."""

    clock_rate: ClockRate | None = None
    sensor: SensorFault | None = None
    actuator: ActuatorFault | None = None
    receive_jitter: ReceiveJitter | None = None

    @property
    def names(self) -> tuple[str, ...]:
        """Fault family names present (e.g. ``sensor_frozen``, ``actuator_weak``)."""
        names = []
        if self.clock_rate:
            names.append("clock_rate")
        if self.sensor:
            names.append(f"sensor_{self.sensor.kind}")
        if self.actuator:
            names.append(f"actuator_{self.actuator.kind}")
        if self.receive_jitter:
            names.append("receive_jitter")
        return tuple(names)

    def as_dict(self) -> dict[str, dict[str, Any]]:
        """Return ``{family: truth}`` of the present faults (JSON-ready)."""
        out: dict[str, dict[str, Any]] = {}
        for field_name in ("clock_rate", "sensor", "actuator", "receive_jitter"):
            value = getattr(self, field_name)
            if value is not None:
                name = {"sensor": f"sensor_{getattr(value, 'kind', '')}",
                        "actuator": f"actuator_{getattr(value, 'kind', '')}"}.get(
                            field_name, field_name)
                out[name] = asdict(value)
        return out


def _draw(family: str, name: str, rng: np.random.Generator) -> float:
    return range_of(family, name).draw(rng)


def draw_fault(family: str, rng: np.random.Generator, *, rate_hz: float, duration_s: float,
               sensors: int, cells: int) -> Faults:
    """Draw the fault ``family`` for a recording with ``sensors`` sensors and ``cells`` actuators.

    ``independent_drive`` is a drive, not a fault: it returns no fault (the configuration's
    ``independent_drive`` flag carries it).

    Raises:
        FaultError: an unknown family, or a sensor (actuator) fault with fewer than 4
            sensors (actuators): nothing to compare the faulty one with.

    """
    if family not in FAULT_FAMILIES:
        raise FaultError(f"unknown fault {family!r}; known: {list(FAULT_FAMILIES)}")
    if ((family.startswith("sensor_") and sensors < 4)
            or (family.startswith("actuator_") and cells < 4)):
        raise FaultError(f"{family} needs >= 4 sensors or actuators to single one out")
    if family == "clock_rate":
        return Faults(clock_rate=ClockRate(_draw(family, "ppm", rng)))
    if family == "sensor_frozen":
        start = round(_draw(family, "freeze_fraction", rng) * duration_s, 3)
        return Faults(sensor=SensorFault("frozen", int(rng.integers(sensors)), start))
    if family == "sensor_flat":
        value = round(_draw(family, "value_degc", rng), 2)
        return Faults(sensor=SensorFault("flat", int(rng.integers(sensors)), 0.0, value))
    if family == "sensor_jump":
        count = int(rng.integers(2, 4))
        times = np.sort(rng.uniform(0.15, 0.85, count)) * duration_s
        steps = rng.choice([-1.0, 1.0], count) * np.array(
            [_draw(family, "step_degc", rng) for _ in range(count)])
        jumps = tuple((round(float(t), 3), round(float(s), 2)) for t, s in
                      zip(times, steps, strict=True))
        return Faults(sensor=SensorFault("jump", int(rng.integers(sensors)), jumps[0][0],
                                         jumps=jumps))
    if family in ("actuator_weak", "actuator_dead"):
        kind = family.removeprefix("actuator_")
        return Faults(actuator=ActuatorFault(kind, int(rng.integers(cells)),
                                             round(_draw(family, "fraction", rng), 3)))
    if family == "receive_jitter":
        mean = _draw(family, "jitter_periods", rng) / rate_hz
        count = int(rng.integers(2, 4))
        # one burst per equal share of the middle of the record, so bursts never overlap
        edges = np.linspace(0.1, 0.9, count + 1) * duration_s
        bursts = []
        for a, b in pairwise(edges):
            length = float(rng.uniform(0.1, 0.3))
            start = float(rng.uniform(a, b - length - 0.2))
            bursts.append((round(start, 3), round(length, 3),
                           round(_draw(family, "burst_late_s", rng), 4)))
        return Faults(receive_jitter=ReceiveJitter(mean, tuple(bursts)))
    return Faults()
