"""How each candidate effect is fitted on top of a model state.

Every candidate is refitted jointly with the per-actuator law on training rows and scored on
held-out rows. Unknowns with no closed-form Jacobian are scanned: the command shift (role
``INPUT_SHIFT``) on whole command periods, then on ``DELAY_STEP`` fractions of a period (the
command interpolated between neighbouring commands); the play thresholds (role ``PLAY``) are
screened with non-negative weights on a grid of the command range (:mod:`.playfit`). Every
other effect is fitted from each of its own starting points
(:meth:`es_physics.effects.Effect.starts`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

import numpy as np

from es_calibration.data.delayrange import (
    DELAY_STEP,
    LOWEST_SHIFT_PERIODS,
    RESCAN_PERIODS,
    longest_whole_shift,
)
from es_calibration.model.composite import CompositeModel
from es_calibration.search.playfit import play_states
from es_calibration.search.state import (
    ModelState,
    Workspace,
    extend_global,
    extend_local,
    fit_state,
)
from es_common.arrays import FloatArray
from es_physics.effects import Role, get

#: An accepted shift is refined (every trial refitted) this many command periods either side.
REFINE_PERIODS: Final = 0.5
#: Step of the rescan's first, coarse pass [command periods].
RESCAN_COARSE: Final = 0.25


def lowest_shift(ws: Workspace) -> float:
    """Return the smallest command shift searched [command periods]: a delay of DELAY_STEP.

    With lock-step stamps and a command not yet in effect at its own stamp, a shift of s is a
    delay of s + 1 period, so the shift may be down to DELAY_STEP - 1 (a fractional delay
    below one period).
    """
    a = ws.aligned
    late = a.has_same_stamps and not a.include_same_stamp
    return LOWEST_SHIFT_PERIODS if late else DELAY_STEP


def candidate_states(
    ws: Workspace, state: ModelState, name: str, duration: float
) -> list[ModelState]:
    """Return fitted states of ``state`` plus effect ``name`` (several starts or grid points)."""
    model = CompositeModel((*state.model.effects, name), operators=state.model.operators or 1)
    local0 = extend_local(state, model)
    role = get(name).role
    if role is Role.INPUT_SHIFT:
        out = _shift_states(ws, state, model, local0)
    elif role is Role.PLAY:
        out = play_states(ws, state, local0)
    else:
        train, held = ws.input_pair(state.delay_s, state.play_thresholds)
        out = [
            fit_state(
                model,
                train,
                held,
                local0,
                extend_global(state, model, {f"{name}.{k}": v for k, v in start.items()}),
                delay_s=state.delay_s,
                thresholds=state.thresholds,
            )
            for start in get(name).starts(duration)
        ]
    if model.shift is not None and len(model.effects) > 1:
        # the shift was scanned with a model that lacked the other effects (a play operator's
        # phase lag looks like a delay): scan it again with the whole refitted model
        out.append(_rescan_shift(ws, min(out, key=lambda s: s.fit.total_cost)))
    if role is Role.INPUT_SHIFT and model.play is not None:
        # and the play thresholds were scanned without the shift: scan them again with it
        out.extend(_replay(ws, min(out, key=lambda s: s.fit.total_cost)))
    return out


def _replay(ws: Workspace, state: ModelState) -> list[ModelState]:
    """Return ``state`` with its play operators scanned again from none (shift kept)."""
    play = state.model.play
    assert play is not None  # called only for a model with a play effect
    reduced = CompositeModel(tuple(e for e in state.model.effects if e != play.name))
    train, held = ws.input_pair(state.delay_s, None)
    without = fit_state(
        reduced,
        train,
        held,
        state.fit.local,
        extend_global(state, reduced, {}),
        delay_s=state.delay_s,
        thresholds=(),
    )
    return play_states(ws, without, without.fit.local)


def _rescan_shift(ws: Workspace, state: ModelState) -> ModelState:
    """Scan ``state``'s shift again within ``RESCAN_PERIODS`` of it; refit at the best one.

    The play operators are taken at the whole shift below each trial (one play pass per
    whole shift); the refit uses them at the exact shift.
    """
    period = ws.aligned.command_period
    thresholds = state.play_thresholds
    plays: dict[float, FloatArray] = {}

    def cost(periods: float) -> float:
        whole = float(np.floor(periods + 1e-9))
        if thresholds is not None and whole not in plays:
            plays[whole] = ws.play_pair(thresholds, whole * period)[0]
        shifted = ws.inputs(ws.fit_rows, periods * period, plays.get(whole))
        pred = state.model.evaluate(state.fit.local, state.fit.glob, shifted, False).prediction
        return float(np.sum(np.where(shifted.valid, shifted.displacement - pred, 0.0) ** 2))

    center = state.delay_s / period
    best = center
    # coarse steps over the whole window, then DELAY_STEP around the best coarse one
    for half_width, step in ((RESCAN_PERIODS, RESCAN_COARSE), (RESCAN_COARSE, DELAY_STEP)):
        steps = round(half_width / step)
        grid = best + step * np.arange(-steps, steps + 1)
        grid = grid[grid >= lowest_shift(ws) - 1e-9]
        best = float(grid[int(np.argmin([cost(d) for d in grid]))])
    if abs(best - center) < 0.5 * DELAY_STEP:
        return state
    train, held = ws.input_pair(best * period, thresholds)
    return fit_state(
        state.model,
        train,
        held,
        state.fit.local,
        state.fit.glob,
        delay_s=best * period,
        thresholds=state.thresholds,
    )


def _shift_states(
    ws: Workspace, state: ModelState, model: CompositeModel, local0: FloatArray
) -> list[ModelState]:
    """Scan command shifts with the current law, then refit along the best period.

    Whole command periods first (1 to ``longest_whole_shift``, the current law held: a cheap
    way to find the right period); then, within a period either side of the best whole
    shift, a golden-section search of the training cost with the law refitted at every trial
    shift (a law fitted without the shift is biased towards whole shifts), on the grid of
    ``DELAY_STEP`` fractions of a period. Every refitted trial is returned.
    """
    period = ws.aligned.command_period
    thresholds = state.play_thresholds
    n_max = longest_whole_shift(period)
    play = None if thresholds is None else ws.play_pair(thresholds, state.delay_s)[0]

    def cost(periods: float) -> float:
        shifted = ws.inputs(ws.fit_rows, periods * period, play)
        pred = state.model.evaluate(state.fit.local, state.fit.glob, shifted, False).prediction
        return float(np.sum(np.where(shifted.valid, shifted.displacement - pred, 0.0) ** 2))

    lowest = lowest_shift(ws)
    whole = np.arange(np.ceil(lowest), n_max + 1, dtype=np.float64)
    best_j = float(whole[int(np.argmin([cost(j) for j in whole]))])
    tried: dict[int, ModelState] = {}

    def refit(step: int) -> float:
        if step not in tried:
            d = step * DELAY_STEP * period
            train, held = ws.input_pair(d, thresholds)
            tried[step] = fit_state(
                model,
                train,
                held,
                local0,
                extend_global(state, model, {}),
                delay_s=d,
                thresholds=state.thresholds,
                max_iter=15,
            )
        return tried[step].fit.total_cost

    per_period = round(1.0 / DELAY_STEP)
    lo = max(round(best_j * per_period) - per_period, round(lowest * per_period))
    hi = min(round(best_j * per_period) + per_period, n_max * per_period)
    _golden(refit, lo, hi)
    return list(tried.values())


def _golden(cost: Callable[[int], float], lo: int, hi: int) -> int:
    """Return the step in [lo, hi] of least ``cost`` (golden section, then the last few)."""
    golden = (5.0**0.5 - 1.0) / 2.0
    while hi - lo > 3:
        c = round(hi - golden * (hi - lo))
        d = round(lo + golden * (hi - lo))
        if c == d:
            d = c + 1
        if cost(c) <= cost(d):
            hi = d
        else:
            lo = c
    return min(range(lo, hi + 1), key=cost)


def refine_shift(ws: Workspace, state: ModelState) -> ModelState:
    """Return ``state`` with its shift refined within ``REFINE_PERIODS``, all refitted.

    The shift was found before the effects added after it; a law and effects fitted at the
    old shift hold a scan with them fixed near it, so here every trial shift is refitted
    (golden section on ``DELAY_STEP`` steps). Without a shift, or with it alone, ``state``.
    """
    if state.model.shift is None or len(state.model.effects) < 2:
        return state
    period = ws.aligned.command_period
    tried: dict[int, ModelState] = {}

    def refit(step: int) -> float:
        if step not in tried:
            d = step * DELAY_STEP * period
            train, held = ws.input_pair(d, state.play_thresholds)
            tried[step] = fit_state(
                state.model,
                train,
                held,
                state.fit.local,
                state.fit.glob,
                delay_s=d,
                thresholds=state.thresholds,
                max_iter=15,
            )
        return tried[step].fit.total_cost

    center = round(state.delay_s / period / DELAY_STEP)
    half = round(REFINE_PERIODS / DELAY_STEP)
    lowest = round(lowest_shift(ws) / DELAY_STEP)
    best = tried[_golden(refit, max(center - half, lowest), center + half)]
    return best if best.fit.total_cost < state.fit.total_cost else state
