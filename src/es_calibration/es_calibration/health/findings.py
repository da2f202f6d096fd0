"""One finding about the recording's health, in the shape calibration.json writes (``health``).

The shape is calibration.json's (es_calibration.output.schema); every health check (timing, sensors,
actuators) returns :class:`Finding` values.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Final

#: The kinds of finding, one definition.
KINDS: Final = (
    "clock_rate",
    "receive_jitter",
    "late_burst",
    "sensor_frozen",
    "sensor_flat",
    "sensor_out_of_range",
    "sensor_jump",
    "sensor_dropout",
    "sensor_noise_change",
    "actuator_outlier",
    "actuator_dead",
    "actuator_weak",
    "actuator_saturating",
)


class FindingKindError(ValueError):
    """A finding of a kind that is not one of ``KINDS``."""


@dataclass(frozen=True)
class Finding:
    """A fault of the recording: what, where, when, how large, in words, and what was done.

    Attributes:
        kind: one of ``KINDS``.
        subject: who it concerns, e.g. "sensor 3 (0, 3)", "displacement logger".
        index: sensor or actuator index (row-major), None for the recording.
        row, col: its grid position (None for the recording).
        start_s, end_s: its time span (s from the record's start).
        value: its size in ``unit`` (None: no size).
        unit: e.g. "ppm".
        sentence: a plain sentence a user understands.
        action: what the tool did about it.

    Raises:
        FindingKindError: ``kind`` is not one of ``KINDS``.

    """

    kind: str
    subject: str
    index: int | None
    row: int | None
    col: int | None
    start_s: float
    end_s: float
    value: float | None
    unit: str
    sentence: str
    action: str

    def __post_init__(self) -> None:
        """Check the kind."""
        if self.kind not in KINDS:
            raise FindingKindError(f"unknown finding kind {self.kind!r} (expected one of {KINDS})")

    def as_dict(self) -> dict[str, Any]:
        """Return the finding as calibration.json writes it (``health.findings``)."""
        return asdict(self)
