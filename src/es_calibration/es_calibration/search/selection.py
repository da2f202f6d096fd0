"""Which effects the data contain: forward selection with a backward check, held-out scored.

Forward: every remaining candidate is refitted jointly with the per-actuator law on training
rows and scored on held-out rows with a Bayesian information criterion whose sample count is
the *effective* number of independent held-out residuals (n / integrated autocorrelation
time), so that a correlated residual cannot buy a spurious effect; of the residuals before
and after the candidate, the less correlated one counts (a candidate that explains the
structure which made the residual correlated is not discounted by it). A candidate passes only
when it lowers that criterion, cuts the held-out RMS by at least ``MIN_RELATIVE_GAIN``, has
physical parameter values and keeps them when each actuator may carry a constant offset
(:mod:`.offsets`: else it stood in for one). Of the passing candidates, the one with the
lowest held-out RMS is added, and the round repeats (the criterion's effective counts differ
between candidates, so it would prefer a candidate that leaves a whiter but larger residual
than a rival).

Backward: with two or more effects accepted, each is taken out in turn (the rest refitted
from the current values) and scored the same way; an effect whose removal the criterion
prefers, or without which the held-out RMS rises by less than ``MIN_RELATIVE_GAIN``, is
dropped (the least useful first) until every remaining effect is needed. This undoes a
forward step that an effect added later made redundant (e.g. a small play operator standing
in for part of a delay).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from es_calibration.model.composite import CANDIDATES, CompositeModel
from es_calibration.search.offsets import offset_stand_in
from es_calibration.search.playfit import without_weakest_operator
from es_calibration.search.scans import candidate_states, refine_shift
from es_calibration.search.state import (
    MIN_RELATIVE_GAIN,
    ModelState,
    Workspace,
    effect_parameters,
    effective_count,
    extend_global,
    fit_state,
    information_delta,
    undetermined,
)
from es_physics.effects import Role, get
from es_physics.effects.identifiable import RecordSpan, identification_problem

#: Held-out RMS below which nothing is worth explaining [m] (far below interferometer noise).
RESOLUTION_FLOOR_M: Final = 1e-12

#: How a refused stand-in's reason starts (calibration.json ``candidates``).
STAND_IN: Final = "stand-in: "

#: One accepted effect: (name, state before it, state with it).
Step = tuple[str, ModelState, ModelState]


@dataclass
class CandidateScore:
    """One candidate's outcome in one round of the search.

    In a backward round ``rms_before_m`` is the held-out RMS without the effect,
    ``rms_after_m`` with it, and ``accepted`` says the effect stays.
    """

    name: str
    rms_before_m: float
    rms_after_m: float
    delta_ic: float
    accepted: bool
    reason: str
    parameters: dict[str, float] = field(default_factory=dict)


@dataclass
class RoundRecord:
    """All candidates tried in one round and the one added or removed (if any).

    ``step`` is ``"forward"`` or ``"backward"``.
    """

    scores: list[CandidateScore]
    added: str | None
    step: str = "forward"
    removed: str | None = None


def subset_state(ws: Workspace, state: ModelState, keep: Sequence[str]) -> ModelState:
    """Refit ``state``'s model reduced to the effects ``keep``, from its current values."""
    model = CompositeModel(tuple(keep), operators=state.model.operators or 1)
    delay = state.delay_s if model.shift else 0.0
    thresholds = state.thresholds if model.play else ()
    train, held = ws.input_pair(delay, thresholds if model.play else None)
    local = state.fit.local[:, : len(model.local_names)]
    return fit_state(
        model,
        train,
        held,
        local,
        extend_global(state, model, {}),
        delay_s=delay,
        thresholds=thresholds,
    )


def effect_unknowns(state: ModelState, name: str, n_actuators: int) -> int:
    """Return how many unknowns effect ``name`` has in ``state`` (play: per operator)."""
    effect = get(name)
    order = state.model.operators if effect is state.model.play else 1
    return effect.added_parameters(n_actuators, order)


def record_span(ws: Workspace) -> RecordSpan:
    """Return what the workspace's record spans: temperatures, sample period, length."""
    a = ws.aligned
    temperature = a.temperature[:, ws.actuators]
    finite = temperature[np.isfinite(temperature)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    return RecordSpan(low, high, 1.0 / a.sample_rate, float(a.t[-1] - a.t[0]), a.stamp_jitter_s)


def _verdict(
    name: str,
    params: dict[str, float],
    before: ModelState,
    after: ModelState,
    delta: float,
    *,
    span: RecordSpan,
) -> str:
    """Return "passes" or why adding ``name`` (``before`` -> ``after``) does not pay.

    A parameter outside what the record can show (``span``, the effect's
    :attr:`~es_physics.effects.Effect.identifiable` rules) makes the effect a stand-in.
    """
    gain = 1.0 - after.heldout_rms / max(before.heldout_rms, 1e-300)
    effect = get(name)
    problem = effect.problem(params) or undetermined(after, name)
    if problem:
        return f"unphysical: {problem}"
    outside = identification_problem(effect.identifiable, params, span)
    if outside:
        return f"{STAND_IN}{outside}"
    if before.heldout_rms < RESOLUTION_FLOOR_M:
        return "residual already below resolution"
    if delta >= 0:
        return f"information criterion does not improve (dBIC = {delta:+.1f})"
    if gain < MIN_RELATIVE_GAIN:
        return f"held-out RMS cut {100 * gain:.2f} % < {100 * MIN_RELATIVE_GAIN:.0f} %"
    return "passes"


def _forward_round(
    ws: Workspace, state: ModelState, candidates: Sequence[str]
) -> tuple[RoundRecord, ModelState | None]:
    """Try every remaining candidate on top of ``state``; return the record and the best."""
    duration = float(ws.aligned.t[-1])
    A = len(ws.actuators)
    _, held = ws.input_pair(state.delay_s, state.play_thresholds)
    n_eff = effective_count(ws, state, held)
    span = record_span(ws)
    scores: list[CandidateScore] = []
    passing: list[tuple[str, ModelState]] = []
    for name in (c for c in candidates if not state.model.has(c)):
        effect = get(name)
        if effect.role is Role.SPATIAL and A < 2:
            continue
        new = min(candidate_states(ws, state, name, duration), key=lambda s: s.fit.total_cost)
        params = effect_parameters(new, name, ws.aligned)
        # the structure a candidate explains made the old residual correlated: a residual
        # it leaves whiter counts as many independent residuals as it then has
        train_new, held_new = ws.input_pair(new.delay_s, new.play_thresholds)
        n_new = max(n_eff, effective_count(ws, new, held_new))
        delta = information_delta(
            state.heldout_sse, new.heldout_sse, n_new, effect_unknowns(new, name, A)
        )
        reason = _verdict(name, params, state, new, delta, span=span)
        if reason == "passes" and (offset := offset_stand_in(new, name, train_new, ws.aligned)):
            reason = f"{STAND_IN}{offset}"
        ok = reason == "passes"
        scores.append(
            CandidateScore(name, state.heldout_rms, new.heldout_rms, delta, ok, reason, params)
        )
        if ok:
            passing.append((name, new))
    if not passing:
        return RoundRecord(scores, None), None
    # the criterion admits; of the admitted rivals, the one that predicts the held-out rows
    # best is added (its own criterion also counts how white its residual is, so it can
    # prefer a rival that leaves a whiter but larger residual)
    name, new = min(passing, key=lambda p: p[1].heldout_rms)
    for s in scores:
        s.accepted = s.name == name
    return RoundRecord(scores, name), new


def _backward_round(ws: Workspace, state: ModelState) -> tuple[RoundRecord, ModelState | None]:
    """Take each effect of ``state`` out in turn; return the record and the reduced state."""
    A = len(ws.actuators)
    _, held = ws.input_pair(state.delay_s, state.play_thresholds)
    n_eff = effective_count(ws, state, held)
    span = record_span(ws)
    scores: list[CandidateScore] = []
    drop: tuple[float, str, ModelState] | None = None
    for name in state.model.effects:
        keep = [e for e in state.model.effects if e != name]
        without = subset_state(ws, state, keep)
        params = effect_parameters(state, name, ws.aligned)
        delta = information_delta(
            without.heldout_sse, state.heldout_sse, n_eff, effect_unknowns(state, name, A)
        )
        reason = _verdict(name, params, without, state, delta, span=span)
        needed = reason == "passes"
        scores.append(
            CandidateScore(
                name,
                without.heldout_rms,
                state.heldout_rms,
                delta,
                needed,
                "still needed" if needed else f"removed: {reason}",
                params,
            )
        )
        if not needed and (drop is None or delta > drop[0]):
            drop = (delta, name, without)
    if drop is None:
        return RoundRecord(scores, None, step="backward"), None
    for s in scores:
        s.accepted = s.name != drop[1]
        if s.accepted:
            s.reason = "kept (another effect removed first)"
    return RoundRecord(scores, None, step="backward", removed=drop[1]), drop[2]


def settle_operators(ws: Workspace, state: ModelState) -> ModelState:
    """Return ``state`` with play operators dropped while the play's weights are unphysical.

    A joint refit after a later effect can push a play operator's weight to zero or below
    (the later effect explains what that operator did); the weakest operator goes, not the
    whole play effect (the backward check would otherwise drop an effect it needs).
    """
    while (play := state.model.play) is not None and play.problem(
        effect_parameters(state, play.name, ws.aligned)
    ):
        reduced = without_weakest_operator(ws, state)
        if reduced is None:
            break
        state = reduced
    return state


def _chain(ws: Workspace, base: ModelState, final: ModelState) -> list[Step]:
    """Return the steps base -> final in ``final``'s effect order (prefix models refitted)."""
    steps: list[Step] = []
    previous = base
    names = final.model.effects
    for i, name in enumerate(names):
        current = final if i == len(names) - 1 else subset_state(ws, final, names[: i + 1])
        steps.append((name, previous, current))
        previous = current
    return steps


def search_effects(
    ws: Workspace, base: ModelState, candidates: Sequence[str] = CANDIDATES
) -> tuple[ModelState, list[Step], list[RoundRecord]]:
    """Forward selection, then the backward check; return (final, steps, rounds)."""
    state = base
    added: list[Step] = []
    rounds: list[RoundRecord] = []
    while True:
        record, new = _forward_round(ws, state, candidates)
        rounds.append(record)
        if new is None or record.added is None:
            break
        new = settle_operators(ws, refine_shift(ws, new))
        added.append((record.added, state, new))
        state = new
    removed = False
    while len(state.model.effects) >= 2:
        record, reduced = _backward_round(ws, state)
        rounds.append(record)
        if reduced is None:
            break
        state, removed = reduced, True
    if removed:
        added = _chain(ws, base, state)
    return state, added, rounds


def preferred_final(new: ModelState, old: ModelState) -> bool:
    """Return whether the final model ``new`` is preferred to ``old`` (held-out RMS, parsimony).

    With fewer effects, ``new`` is preferred unless its held-out RMS is more than
    ``MIN_RELATIVE_GAIN`` above ``old``'s; with as many, when its held-out RMS is lower; with
    more, when it is lower by at least ``MIN_RELATIVE_GAIN``.
    """
    n_new, n_old = len(new.model.effects), len(old.model.effects)
    if n_new < n_old:
        return new.heldout_rms <= (1.0 + MIN_RELATIVE_GAIN) * old.heldout_rms
    if n_new == n_old:
        return new.heldout_rms < old.heldout_rms
    return new.heldout_rms < (1.0 - MIN_RELATIVE_GAIN) * old.heldout_rms
