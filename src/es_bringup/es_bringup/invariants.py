"""Invariants every closed-loop run must keep (checked on its bag and the nodes' own counts).

1. Nothing non-finite and nothing beyond the amplifier limit was ever commanded: every value
   recorded on /dm/command is finite and within +-``v_limit``.
2. Nothing was lost on the way to the bag: for every recorded data topic, the number of
   messages its publishers say they published equals the number of messages in the bag, and
   the recorder wrote everything it received, with no loss reported by the middleware.

Pure (no rclpy); the counts of published messages come from the nodes' exit logs (see
:func:`published_counts_from_log`), the recorder's from its exit log.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from es_common.arrays import FloatArray

#: Line a node logs at exit for each topic it published on (es_dm convention):
#: ``published <topic>: <count>``; the recorder logs ``<topic>: received <n>, written <m>``.
_PUBLISHED = re.compile(r"published (/[\w/]+):? (\d+)")
_RECORDED = re.compile(
    r"(/[\w/]+): received (\d+), written (\d+)(?:, lost before reception (\d+))?"
    r"(?:, missed (?:\d+|unknown))?(?:, not received (\d+))?"
)


@dataclass
class InvariantReport:
    """What was checked for one run and what failed (empty ``failures`` = all held)."""

    command_count: int = 0
    command_max_abs_v: float = 0.0
    command_non_finite: int = 0
    command_beyond_limit: int = 0
    published: dict[str, int] = field(default_factory=dict)
    recorded: dict[str, int] = field(default_factory=dict)
    #: /diagnostics reports a node sent before the recorder had matched it (start-up).
    diagnostics_before_recording: dict[str, int] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when every invariant held."""
        return not self.failures


def check_commands(
    commands: FloatArray, v_limit: float, report: InvariantReport
) -> None:
    """Check recorded /dm/command values (any shape, first axis = messages) into ``report``."""
    values = np.asarray(commands, dtype=np.float64)
    finite = np.isfinite(values)
    report.command_count = int(values.shape[0]) if values.ndim else 0
    report.command_non_finite = int(np.count_nonzero(~finite))
    report.command_beyond_limit = int(np.count_nonzero(np.abs(values[finite]) > v_limit))
    report.command_max_abs_v = float(np.max(np.abs(values[finite]), initial=0.0))
    if report.command_non_finite:
        report.failures.append(f"/dm/command: {report.command_non_finite} non-finite values")
    if report.command_beyond_limit:
        report.failures.append(
            f"/dm/command: {report.command_beyond_limit} values beyond +-{v_limit:g} V "
            f"(max |V| {report.command_max_abs_v:.6g})"
        )


def contract_name(topic: str, names: Iterable[str]) -> str:
    """Return the contract topic a (namespaced, ``/<ns>/dm/...``) topic stands for."""
    for name in names:
        if topic == name or topic.endswith(name):
            return name
    return topic


def published_counts_from_log(
    lines: Iterable[str], names: Iterable[str] = ()
) -> dict[str, int]:
    """Return ``{topic: count}`` from ``published <topic>: <n>`` lines (the last per topic).

    Topics that end in one of ``names`` (a graph run below a namespace) count as that name.
    """
    known = tuple(names)
    counts: dict[str, int] = {}
    for line in lines:
        for topic, count in _PUBLISHED.findall(line):
            counts[contract_name(topic, known)] = int(count)
    return counts


class RecorderCounts(NamedTuple):
    """One topic's counts from the recorder's closing log.

    ``not_received``: what the recorder knew published and not received when it stopped
    (0 when its log does not say, or says ``unknown``).
    """

    received: int
    written: int
    lost: int = 0
    not_received: int = 0


def recorder_counts_from_log(lines: Iterable[str]) -> dict[str, RecorderCounts]:
    """Return the recorder's closing counts per topic from its log."""
    counts: dict[str, RecorderCounts] = {}
    for line in lines:
        for topic, received, written, lost, missing in _RECORDED.findall(line):
            counts[topic] = RecorderCounts(
                int(received), int(written), int(lost or 0), int(missing or 0)
            )
    return counts


def recorder_holes(counts: Mapping[str, RecorderCounts]) -> list[str]:
    """Describe each topic with messages the recorder knew it had not received at its stop."""
    return [
        f"{topic}: {c.not_received} published messages not received by the recorder"
        for topic, c in counts.items()
        if c.not_received
    ]


def check_recorder(counts: Mapping[str, RecorderCounts], report: InvariantReport) -> None:
    """Fail on what the recorder's closing counts show lost.

    It did not write what it received, the middleware lost messages before reception, or it
    knew of published messages it had not received when it stopped.
    """
    if not counts:
        report.failures.append("the recorder reported no counts")
    for topic, c in counts.items():
        if c.written != c.received:
            report.failures.append(f"{topic}: recorder received {c.received}, wrote {c.written}")
        if c.lost:
            report.failures.append(f"{topic}: middleware lost {c.lost} before the recorder")
    report.failures.extend(recorder_holes(counts))


def check_counts(
    published: Mapping[str, int],
    in_bag: Mapping[str, int],
    report: InvariantReport,
    topics: Iterable[str],
) -> None:
    """Compare publishers' counts with the bag's for ``topics`` into ``report``.

    A topic with no published count (no node reported one) is a failure: an invariant that
    cannot be checked does not hold.
    """
    for topic in topics:
        sent = published.get(topic)
        got = in_bag.get(topic, 0)
        report.recorded[topic] = got
        if sent is None:
            report.failures.append(f"{topic}: no publisher reported a count")
            continue
        report.published[topic] = sent
        if sent != got:
            report.failures.append(f"{topic}: {sent} published, {got} in the bag")
