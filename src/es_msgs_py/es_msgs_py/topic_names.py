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

#: History depth of every /dm endpoint: one second of the fastest stream (set points and
#: commands at 1 kHz). Reliable delivery resends only what the writer still holds, and a
#: reader drops its oldest sample when its history is full: with the contract's default of
#: 10, a reader that is not serviced for 10 periods (10 ms at 1 kHz, one scheduler stall on
#: a busy machine) loses messages. A history only fills while samples are unacknowledged or
#: untaken, so the memory bound, DM_DEPTH messages per endpoint (32 MiB at 4096 doubles),
#: is reached only during such a stall.
DM_DEPTH: Final = 1000
