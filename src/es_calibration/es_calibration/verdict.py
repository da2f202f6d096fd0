"""The calibration's verdict: trusted, provisional or unusable, with the reasons.

- ``unusable``: the law is not physical for most actuators (the fit failed), the grid's
  law lies outside the physical intervals (the thesis's 95 % intervals widened
  ``PHYSICAL_WIDENING`` times), or fewer than ``MIN_KEPT_FRACTION`` of the data were kept;
- ``provisional``: the held-out error stays above ``FAR_ABOVE_FLOOR`` times the noise floor
  with structure left, health findings took data out or flagged an actuator, the time base
  rests on a timing finding (a clock-rate difference corrected, receive jitter, late
  bursts), an effect did not hold on the record's halves, or fewer than
  ``KEPT_FOR_TRUSTED`` of the data were kept;
- ``trusted`` otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np

from es_calibration.health.findings import Finding
from es_physics.params import THESIS_INTERVALS_95, ActuatorParams

LEVELS: Final = ("trusted", "provisional", "unusable")
#: Exit status of ``calibrate`` per level.
EXIT_STATUS: Final = {"trusted": 0, "provisional": 3, "unusable": 4}
#: Exit statuses of a calibration that wrote a usable parameters file.
WRITTEN: Final = (EXIT_STATUS["trusted"], EXIT_STATUS["provisional"])
#: Held-out RMS over the noise floor beyond which, with structure left, it is provisional.
FAR_ABOVE_FLOOR: Final = 2.0
#: The physical intervals: the thesis's 95 % intervals, each bound this many times wider.
PHYSICAL_WIDENING: Final = 3.0
#: Kept share of the data below which the result is unusable ...
MIN_KEPT_FRACTION: Final = 0.1
#: ... and below which it is provisional.
KEPT_FOR_TRUSTED: Final = 0.5
#: Kinds of findings that take data out or leave an actuator the feedforward cannot fix.
_PROVISIONAL_KINDS: Final = ("actuator_dead", "actuator_saturating")
#: Timing findings: the time base was corrected from an estimate, or stamps were late.
_TIMING_KINDS: Final = ("clock_rate", "receive_jitter", "late_burst")


@dataclass(frozen=True)
class Verdict:
    """The level and the reasons for it (empty when trusted)."""

    level: str
    reasons: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """Return calibration.json's ``verdict``."""
        return {"level": self.level, "reasons": list(self.reasons)}


def _physical_bounds(name: str) -> tuple[float, float]:
    low, high = THESIS_INTERVALS_95[name]
    widen = PHYSICAL_WIDENING
    return (low * widen if low < 0 else low / widen, high / widen if high < 0 else high * widen)


def law_problems(params: ActuatorParams, temperatures: tuple[float, float]) -> list[str]:
    """Return why the fitted law is not usable (empty: it is).

    Args:
        params: per-actuator law maps.
        temperatures: lowest and highest recorded temperature [degC].

    """
    reasons = []
    with np.errstate(all="ignore"):
        M = np.stack([np.ravel(params.M(T)) for T in temperatures])
        k = np.stack([np.ravel(params.k(T)) for T in temperatures])
    bad = ~((M > 0) & (k > 0)).all(axis=0)
    if bad.mean() > 0.5:
        reasons.append(
            f"the fit failed for {int(bad.sum())} of {bad.size} actuators (M or k not "
            "positive over the recorded temperatures)"
        )
    for name in THESIS_INTERVALS_95:
        median = float(np.nanmedian(np.asarray(getattr(params, name), np.float64)))
        low, high = _physical_bounds(name)
        if not low <= median <= high:
            reasons.append(
                f"law {name} {median:.3g} (grid median) outside the physical interval "
                f"[{low:.3g}, {high:.3g}]"
            )
    return reasons


def judge(
    *,
    law: list[str],
    kept_fraction: float,
    heldout_rms_m: float,
    noise_floor_m: float,
    unexplained: Sequence[str],
    findings: Sequence[Finding],
    unconfirmed: Sequence[str],
) -> Verdict:
    """Return the verdict (see the module docstring).

    Args:
        law: :func:`law_problems`'s reasons.
        kept_fraction: share of the data kept for the fit.
        heldout_rms_m: the final model's held-out RMS [m].
        noise_floor_m: the noise floor [m].
        unexplained: the structure the final model leaves, in words.
        findings: the health findings.
        unconfirmed: effects that did not hold on the record's halves.

    """
    unusable = list(law)
    if kept_fraction < MIN_KEPT_FRACTION:
        unusable.append(f"only {100 * kept_fraction:.1f} % of the data kept")
    if unusable:
        return Verdict("unusable", unusable)
    reasons = []
    ratio = heldout_rms_m / noise_floor_m if noise_floor_m > 0 else np.inf
    if ratio > FAR_ABOVE_FLOOR and unexplained:
        reasons.append(
            f"held-out error {ratio:.3g}x the noise floor with structure left: "
            f"{unexplained[0]}"
        )
    took_out = [f for f in findings if f.kind.startswith("sensor_")]
    if took_out:
        reasons.append(
            f"{len(took_out)} sensor finding(s) replaced or left out data: "
            + "; ".join(f"{f.kind} {f.subject}" for f in took_out[:5])
        )
    for f in findings:
        if f.kind in _PROVISIONAL_KINDS:
            reasons.append(f"{f.kind} {f.subject}")
    timing = [f for f in findings if f.kind in _TIMING_KINDS]
    if timing:
        reasons.append(
            f"{len(timing)} timing finding(s), the time base rests on their estimate: "
            + "; ".join(f"{f.kind} {f.subject}" for f in timing[:5])
        )
    if unconfirmed:
        reasons.append(
            f"effect(s) not confirmed on the record's halves, written switched off: "
            f"{', '.join(unconfirmed)}"
        )
    if kept_fraction < KEPT_FOR_TRUSTED:
        reasons.append(f"only {100 * kept_fraction:.1f} % of the data kept")
    return Verdict("provisional", reasons) if reasons else Verdict("trusted", [])
