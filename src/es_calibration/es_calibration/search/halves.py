"""Whether the accepted effects hold on independent halves of the record.

The final model is refitted on the first and on the second half of the training and
held-out rows (delay and play thresholds as found); each accepted effect's reported
parameters must agree between the halves (:func:`.agreement.disagreement`): one that
moves was fitted to something else (a real effect keeps its value; one standing in for,
say, a clock drift changes with the part of the record), and the whole record's value
must not take a sign both halves reverse (:func:`_between_halves`).
"""

from __future__ import annotations

from typing import Final

from es_calibration.search.agreement import NotANumberError, disagreement
from es_calibration.search.selection import STAND_IN, CandidateScore, RoundRecord, subset_state
from es_calibration.search.state import ModelState, Workspace, fitted_effect
from es_physics.effects import get

#: A whole-record value must stand this many 1-sigma from 0 for its sign to count.
SIGN_SIGMAS: Final = 2.0


def _half(ws: Workspace, first: bool) -> Workspace:
    """Return a workspace on the first or second half of ``ws``'s rows."""
    t = ws.aligned.t
    middle = 0.5 * (t[0] + t[-1])
    half = Workspace(ws.aligned, ws.actuators, ws.grid)
    half.fit_rows = ws.fit_rows[(t[ws.fit_rows] < middle) == first]
    half.score_rows = ws.score_rows[(t[ws.score_rows] < middle) == first]
    return half


def _between_halves(whole: ModelState, halves: list[dict[str, float]], name: str,
                    ws: Workspace) -> str | None:
    """Return why effect ``name``'s whole-record fit comes from between the halves, or None.

    A real effect's value on the whole record lies among its halves' (near their weighted
    mean). A parameter significant on the whole (beyond ``SIGN_SIGMAS`` 1-sigma) whose sign
    both halves reverse describes no structure inside either half: it takes the difference
    between them (on the independent stand: a temperature curvature standing in for a
    periodic error of the metrology, m3 +2.2e-19 on the whole, -1.2e-19 and -3.6e-20 on the
    halves).
    """
    effect = get(name)
    fit = fitted_effect(whole, effect, ws.aligned)
    values, sigmas = effect.reported(fit), effect.uncertainties(fit)
    for key, sigma in sigmas.items():
        value = values.get(key, 0.0)
        if not abs(value) > SIGN_SIGMAS * sigma:
            continue
        a, b = (h.get(key, value) for h in halves)
        if a * value < 0.0 and b * value < 0.0:
            return (f"{key} {value:.3g} on the whole record, of the other sign on both halves "
                    f"({a:.3g}, {b:.3g}): it follows the difference between them")
    return None


def _moved(name: str, halves: list[ModelState], whole: ModelState, ws: Workspace
           ) -> tuple[str | None, dict]:
    """Return why effect ``name`` moves between the two halves' fits (None: it holds)."""
    effect = get(name)
    fits = [fitted_effect(s, effect, ws.aligned) for s in halves]
    values = [effect.reported(f) for f in fits]
    sigmas = [effect.uncertainties(f) for f in fits]
    params = {f"{k} ({which})": v[k] for which, v in zip(("first", "second"), values,
                                                         strict=True) for k in v}
    try:
        moved = disagreement(values, sigmas)
    except NotANumberError as bad:
        return f"{bad} not a number on a half", params
    if moved is None:
        return _between_halves(whole, values, name, ws), params
    key, a, b, combined = moved
    return (
        f"{key} moves between the record's halves: {a:.3g} vs {b:.3g} (1-sigma {combined:.2g})"
    ), params


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
        why, params = _moved(name, halves, final, ws)
        if why:
            moving.add(name)
        scores.append(CandidateScore(
            name, halves[0].heldout_rms, halves[1].heldout_rms, 0.0, why is None,
            f"{STAND_IN}{why}" if why else "holds on both halves of the record", params,
        ))
    return RoundRecord(scores, None, step="halves"), moving
