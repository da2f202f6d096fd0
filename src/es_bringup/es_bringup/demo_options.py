"""The demo's options: what it runs (scenarios, modes, sections) and how long."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from es_feedforward.feedforward import Mode

#: Closed-loop scenarios of the main job.
SCENARIOS: tuple[str, ...] = ("thesis_ac", "thesis_dc_ac", "dm_exposure")
#: Feedforward modes: the baseline first, then every compensating mode.
MODES: tuple[str, ...] = (
    Mode.UNCOMPENSATED.value,
    *(mode.value for mode in Mode if mode is not Mode.UNCOMPENSATED),
)
#: ``--long`` multiplies every scenario's time scale by this (slower thermal transients).
LONG_FACTOR = 5.0
#: Control rate of the closed-loop runs by default [Hz]: 50 samples per period of the 1 Hz
#: set points (the actuator is quasi-static); ``--long`` keeps each scenario's own rate.
DEFAULT_CONTROL_RATE = 50.0


@dataclass(frozen=True)
class Options:
    """Command-line options of the demo."""

    out: Path
    long: bool
    jobs: int
    scenarios: tuple[str, ...]
    modes: tuple[str, ...]
    loop: bool
    selfsensing: bool = True
