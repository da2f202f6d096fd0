"""Per-actuator values of accepted effects' parameters, where the data support them.

After the search, each accepted effect's :attr:`~es_physics.effects.Effect.local_options`
(e.g. the sensor lag's tau, the self-heating gain) is tried as one value per actuator
instead of one for the grid, on grids of two or more actuators. It is kept only when it pays
on held-out data by the search's own rule: the information criterion with the effective
number of held-out residuals must fall (A - 1 unknowns more), the held-out RMS must fall by
``MIN_RELATIVE_GAIN``, and the grid's median value must stay physical. Otherwise the grid
keeps one value.
"""

from __future__ import annotations

from es_calibration.model.composite import CompositeModel
from es_calibration.search.selection import CandidateScore, RoundRecord, _verdict, record_span
from es_calibration.search.state import (
    ModelState,
    Workspace,
    effect_parameters,
    effective_count,
    extend_global,
    extend_local,
    fit_state,
    information_delta,
)
from es_physics.effects import get

#: ``RoundRecord.step`` of the per-actuator round.
STEP = "per_actuator"


def per_actuator_round(ws: Workspace, state: ModelState) -> tuple[RoundRecord | None, ModelState]:
    """Try each accepted effect's per-actuator options on ``state``; return the record and state.

    The state has the options that pay (it is ``state`` itself when none does); the record
    is None when there is nothing to try (one actuator, or no effect with options).
    """
    A = len(ws.actuators)
    options = [
        (name, p) for name in state.model.effects for p in get(name).local_options
    ]
    if A < 2 or not options:
        return None, state
    _, held = ws.input_pair(state.delay_s, state.play_thresholds)
    n_eff = effective_count(ws, state, held)
    scores: list[CandidateScore] = []
    current = state
    for name, p in options:
        key = f"{name}.{p}"
        model = CompositeModel(
            current.model.effects,
            operators=current.model.operators or 1,
            per_actuator=(*current.model.per_actuator, key),
        )
        train, held = ws.input_pair(current.delay_s, current.play_thresholds)
        new = fit_state(
            model,
            train,
            held,
            extend_local(current, model),
            extend_global(current, model, {}),
            delay_s=current.delay_s,
            thresholds=current.thresholds,
        )
        params = effect_parameters(new, name, ws.aligned)
        delta = information_delta(current.heldout_sse, new.heldout_sse, n_eff, A - 1)
        # the search's own rule
        reason = _verdict(name, params, current, new, delta, span=record_span(ws))
        ok = reason == "passes"
        scores.append(
            CandidateScore(
                f"{key} per actuator",
                current.heldout_rms,
                new.heldout_rms,
                delta,
                ok,
                "one value per actuator" if ok else f"one value for the grid: {reason}",
                params,
            )
        )
        if ok:
            current = new
    kept = [s.name for s in scores if s.accepted]
    return RoundRecord(scores, ", ".join(kept) or None, step=STEP), current
