"""Registry effects that the discovered terms show to be stand-ins.

On a record with an effect in no registry list, a registry effect that only resembles it can
pass the search's information criterion and take part of it (on the independent stand:
frequency dispersion for an amplifier's droop or for creep), and the discovery then finds
only the rest. So once the discovery has added terms, each accepted effect is taken out in
turn, the discovery run again on the model without it, and the two answers compared on the
held-out rows by the same criterion: the effect's unknowns against the difference in terms.
Where the model without the effect, with its own terms, wins, the effect was a stand-in and
goes, and the others are judged again against the new answer (on the stand's creep, 4 x 4:
frequency dispersion went first, then coupling, which had been judged beside it). A registry
effect that explains the same structure with fewer unknowns wins the comparison and stays (a
discovered term never replaces it).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from es_calibration.discovery.terms import Discovery
from es_calibration.search.selection import (
    CandidateScore,
    RoundRecord,
    effect_unknowns,
    subset_state,
)
from es_calibration.search.state import (
    ModelState,
    Workspace,
    effective_count,
    information_delta,
)

#: One accepted effect of the search: its name, the model before it and with it.
Added = tuple[str, ModelState, ModelState]
#: The round's step name in calibration.json's candidates.
STEP = "stand_in"


def _without(ws: Workspace, added: list[Added], index: int) -> list[Added]:
    """Return ``added`` with effect ``index`` taken out of every later model (refitted)."""
    name = added[index][0]
    out = list(added[:index])
    before = added[index][1]
    for later, _, state in added[index + 1:]:
        keep = [e for e in state.model.effects if e != name]
        reduced = subset_state(ws, state, keep)
        out.append((later, before, reduced))
        before = reduced
    return out


def drop_stand_ins(ws: Workspace, base: ModelState, added: list[Added],
                   discovery: Discovery, rediscover: Callable[[ModelState], Discovery]
                   ) -> tuple[list[Added], Discovery, RoundRecord | None]:
    """Return ``added`` and ``discovery`` without the stand-ins, and the round's record.

    Args:
        ws: the screening block (the grid).
        base: the model without any effect.
        added: the accepted effects in order (the last one's model is the final).
        discovery: the discovery's outcome on the final model.
        rediscover: the discovery step on another model of the same block.

    The record is None when nothing was compared (no terms added, no effect accepted).

    """
    if not (discovery.added and added):
        return added, discovery, None
    scores: list[CandidateScore] = []
    removed: list[str] = []
    judged: set[str] = set()
    while True:  # after a removal the rest are judged again, against the new answer
        pending = [i for i in reversed(range(len(added))) if added[i][0] not in judged]
        for index in pending:
            name = added[index][0]
            score, reduced, other = _judge(ws, base, added, index, discovery=discovery,
                                           rediscover=rediscover)
            scores.append(score)
            if not score.accepted:
                added, discovery = reduced, other
                removed.append(name)
                judged = set()
                break
            judged.add(name)
        else:
            break
        if not (discovery.added and added):
            break
    return added, discovery, RoundRecord(scores, None, step=STEP,
                                         removed=", ".join(removed) or None)


def _judge(ws: Workspace, base: ModelState, added: list[Added], index: int, *,
           discovery: Discovery, rediscover: Callable[[ModelState], Discovery]
           ) -> tuple[CandidateScore, list[Added], Discovery]:
    """Compare the model with effect ``index`` and without it, each with its own terms.

    Returns the score (accepted: the effect stays), the effects without it and the
    discovery's answer on the model without it.
    """
    name = added[index][0]
    final = added[-1][2]
    reduced = _without(ws, added, index)
    without = reduced[-1][2] if reduced else base
    other = rediscover(without)
    with_rms = discovery.heldout_rms_after_m
    without_rms = other.heldout_rms_after_m if other.added else other.heldout_rms_before_m
    _, held = ws.input_pair(final.delay_s, final.play_thresholds)
    n_eff = effective_count(ws, final, held)
    extra = (len(other.used) - len(discovery.used)
             - effect_unknowns(final, name, len(ws.actuators)))
    delta = information_delta(without_rms**2, with_rms**2, n_eff, -extra)
    stays = not (np.isfinite(delta) and delta > 0.0)
    reason = ("still needed with the discovered terms" if stays else
              "removed: a stand-in (the model without it and its own discovered terms "
              f"explains the held-out rows better: dBIC of keeping it {delta:+.1f})")
    return CandidateScore(name, without_rms, with_rms, delta, stays, reason,
                          {"terms_without": float(len(other.used)),
                           "terms_with": float(len(discovery.used))}), reduced, other
