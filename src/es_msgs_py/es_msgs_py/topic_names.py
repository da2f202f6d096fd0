"""The contract's topic names (pure: no rclpy, so bag tools and importers can use them)."""

from __future__ import annotations

from typing import Final

HEAT_LOAD: Final = "/dm/heat_load"
TEMPERATURE_RAW: Final = "/dm/temperature/raw"
TEMPERATURE: Final = "/dm/temperature"
SETPOINT: Final = "/dm/setpoint"
COMMAND: Final = "/dm/command"
DISPLACEMENT: Final = "/dm/displacement"
DIAGNOSTICS: Final = "/diagnostics"
CLOCK: Final = "/clock"
#: Latest measured thickness-mode resonance per actuator (grid, Hz; NaN where not measured
#: this cycle): the self-sensing input of the thermal node, published only when the
#: measurement is on.
RESONANCE: Final = "/dm/resonance"
