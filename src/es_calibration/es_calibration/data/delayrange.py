"""The command shifts the delay search considers (one definition for the scans and the edges).

A shift is given in command periods. The scan tries whole periods from the lowest shift up
to :func:`longest_whole_shift`, then fractions of ``DELAY_STEP``; a shift found earlier is
scanned again ``RESCAN_PERIODS`` either side. With lock-step stamps and a command not yet
in effect at its own stamp the shift may be down to ``DELAY_STEP - 1`` period
(``LOWEST_SHIFT_PERIODS``).
"""

from __future__ import annotations

from typing import Final

#: Longest delay searched [s] and in command periods.
MAX_DELAY_S: Final = 0.1
MAX_DELAY_PERIODS: Final = 40
#: Resolution of the delay scan, in command periods.
DELAY_STEP: Final = 0.05
#: A shift found earlier is scanned again this many command periods either side.
RESCAN_PERIODS: Final = 2.5
#: The lowest shift any stamp convention allows [command periods].
LOWEST_SHIFT_PERIODS: Final = DELAY_STEP - 1.0


def longest_whole_shift(period_s: float) -> int:
    """Return the longest whole shift the scan tries [command periods] at ``period_s`` [s]."""
    return int(min(MAX_DELAY_PERIODS, max(1, MAX_DELAY_S / period_s)))


def shift_span(period_s: float) -> tuple[float, float]:
    """Return the lowest and highest shift any search step can reach [command periods]."""
    return LOWEST_SHIFT_PERIODS, longest_whole_shift(period_s) + RESCAN_PERIODS
