"""Fault-case tally of the reliability suite, printed after the test run.

Every test of this directory reports the fault cases it injected through the ``fault_cases``
fixture: what was tried, whether it held (no crash, no non-finite or out-of-limit command,
the documented error or diagnostic, nothing lost), and the commands it checked on the way.
``pytest_terminal_summary`` prints the totals that docs/reliability.md's table states.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest


@dataclass
class Case:
    """One injected fault and its outcome."""

    area: str
    name: str
    held: bool
    detail: str = ""


@dataclass
class Tally:
    """Totals over the whole reliability run."""

    cases: list[Case] = field(default_factory=list)
    commands_checked: int = 0
    non_finite_commands: int = 0
    out_of_limit_commands: int = 0
    crashes: int = 0
    lost_messages: int = 0


TALLY = Tally()


class FaultCases:
    """Collects the cases of one test; :meth:`assert_held` fails the test on any that broke."""

    def __init__(self, tally: Tally) -> None:
        self._tally = tally
        self._mine: list[Case] = []

    def expect(self, area: str, name: str, held: bool, detail: str = "") -> bool:
        """Record one case; return ``held`` so a caller can branch on it."""
        case = Case(area, name, bool(held), detail)
        self._mine.append(case)
        self._tally.cases.append(case)
        return case.held

    def commands(self, checked: int, non_finite: int, out_of_limit: int) -> None:
        """Add what a /dm/command monitor saw."""
        self._tally.commands_checked += checked
        self._tally.non_finite_commands += non_finite
        self._tally.out_of_limit_commands += out_of_limit

    def crashed(self, count: int = 1) -> None:
        """Count node processes that died on their own."""
        self._tally.crashes += count

    def lost(self, count: int) -> None:
        """Count messages that were published but not received or recorded."""
        self._tally.lost_messages += count

    def assert_held(self) -> None:
        """Fail with every case of this test that did not hold."""
        broken = [f"{c.area}: {c.name} ({c.detail})" for c in self._mine if not c.held]
        assert not broken, "fault cases that did not hold:\n  " + "\n  ".join(broken)


@pytest.fixture
def fault_cases() -> Iterator[FaultCases]:
    """Per-test collector feeding the session tally."""
    yield FaultCases(TALLY)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Print the reliability totals (only when reliability tests ran)."""
    if not TALLY.cases:
        return
    held = sum(c.held for c in TALLY.cases)
    areas: dict[str, list[int]] = {}
    for case in TALLY.cases:
        counts = areas.setdefault(case.area, [0, 0])
        counts[0] += 1
        counts[1] += case.held
    write = terminalreporter.write_line
    terminalreporter.section("reliability: fault cases")
    for area, (tried, ok) in sorted(areas.items()):
        write(f"{area}: {tried} tried, {ok} held")
    write(
        f"total: {len(TALLY.cases)} fault cases, {held} held; crashes {TALLY.crashes}; "
        f"/dm/command messages checked {TALLY.commands_checked}: non-finite "
        f"{TALLY.non_finite_commands}, out of limits {TALLY.out_of_limit_commands}; "
        f"lost messages {TALLY.lost_messages}"
    )
    for case in TALLY.cases:
        if not case.held:
            write(f"NOT HELD: {case.area}: {case.name} ({case.detail})")
