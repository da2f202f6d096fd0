"""Whether the accepted effects hold on independent halves of the record.

The final model is refitted on the first and on the second half of the training and
held-out rows (delay and play thresholds as found); each accepted effect's reported
parameters must agree between the halves. A parameter differing by more than
``HALVES_SIGMAS`` combined 1-sigma *and* by more than ``HALVES_RELATIVE`` of its larger
magnitude moves: the effect was fitted to something else (a real effect keeps its value;
one standing in for, say, a clock drift changes with the part of the record).
"""

from __future__ import annotations

from typing import Final

import numpy as np

from es_calibration.search.selection import STAND_IN, CandidateScore, RoundRecord, subset_state
from es_calibration.search.state import ModelState, Workspace, fitted_effect
from es_physics.effects import get

#: Combined 1-sigma uncertainties two halves' values may differ by.
HALVES_SIGMAS: Final = 4.0
#: Share of the larger magnitude two halves' values may differ by (a sign change never).
HALVES_RELATIVE: Final = 0.5


def _half(ws: Workspace, first: bool) -> Workspace:
    """Return a workspace on the first or second half of ``ws``'s rows."""
    t = ws.aligned.t
    middle = 0.5 * (t[0] + t[-1])
    half = Workspace(ws.aligned, ws.actuators, ws.grid)
    half.fit_rows = ws.fit_rows[(t[ws.fit_rows] < middle) == first]
    half.score_rows = ws.score_rows[(t[ws.score_rows] < middle) == first]
    return half


def _moved(name: str, halves: list[ModelState], ws: Workspace) -> tuple[str | None, dict]:
    """Return why effect ``name`` moves between the two halves' fits (None: it holds)."""
    effect = get(name)
    fits = [fitted_effect(s, effect, ws.aligned) for s in halves]
    values = [effect.reported(f) for f in fits]
    sigmas = [effect.uncertainties(f) for f in fits]
    params = {f"{k} ({which})": v[k] for which, v in zip(("first", "second"), values,
                                                         strict=True) for k in v}
    for key in sigmas[0]:
        if key not in values[0] or key not in sigmas[1]:
            continue
        a, b = values[0][key], values[1][key]
        combined = float(np.hypot(sigmas[0][key], sigmas[1][key]))
        gap = abs(a - b)
        if not (np.isfinite(a) and np.isfinite(b)):
            return f"{key} not a number on a half", params
        if gap > HALVES_SIGMAS * combined and gap > HALVES_RELATIVE * max(abs(a), abs(b)):
            return (
                f"{key} moves between the record's halves: {a:.3g} vs {b:.3g} "
                f"(1-sigma {combined:.2g})"
            ), params
    return None, params


def check_halves(ws: Workspace, final: ModelState) -> tuple[RoundRecord | None, set[str]]:
    """Refit ``final`` on each half of the record; return the record and the moving effects.

    The record's scores (step ``"halves"``) are accepted when the effect holds; a moving
    effect's reason starts with ``"stand-in: "``.
    """
    names = final.model.effects
    if not names:
        return None, set()
    halves = [subset_state(_half(ws, first), final, names) for first in (True, False)]
    scores = []
    moving: set[str] = set()
    for name in names:
        why, params = _moved(name, halves, ws)
        if why:
            moving.add(name)
        scores.append(CandidateScore(
            name, halves[0].heldout_rms, halves[1].heldout_rms, 0.0, why is None,
            f"{STAND_IN}{why}" if why else "holds on both halves of the record", params,
        ))
    return RoundRecord(scores, None, step="halves"), moving
