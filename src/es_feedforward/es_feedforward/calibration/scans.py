"""How each candidate effect is fitted on top of a model state.

Every candidate is refitted jointly with the per-actuator law on training rows and scored on
held-out rows. Unknowns with no closed-form Jacobian are scanned: the command shift (role
``INPUT_SHIFT``) on whole command periods, then on ``DELAY_STEP`` fractions of a period (the
command interpolated between neighbouring commands); the play thresholds (role ``PLAY``) on a
logarithmic grid of the command range, refined between the best one's neighbours, one
operator after the other. Every other effect is fitted from each of its own starting points
(:meth:`es_physics.effects.Effect.starts`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np

from es_feedforward.calibration.model import CompositeModel, FloatArray
from es_feedforward.calibration.search import (
    ModelState,
    Workspace,
    effect_parameters,
    effective_count,
    extend_global,
    extend_local,
    fit_state,
    information_delta,
)
from es_physics.effects import Role, get, with_role

#: Longest delay searched [s] and in command periods.
MAX_DELAY_S: Final = 0.1
MAX_DELAY_PERIODS: Final = 40
#: Resolution of the delay scan, in command periods.
DELAY_STEP: Final = 0.05
#: A shift found earlier is scanned again this many command periods either side.
RESCAN_PERIODS: Final = 2.5
#: Hysteresis thresholds tried, as fractions of the command's range.
THRESHOLD_FRACTIONS: Final = (0.005, 0.01, 0.02, 0.04, 0.08, 0.16, 0.3)
#: Thresholds tried between the best coarse threshold's neighbours.
FINE_THRESHOLDS: Final = 5
#: Smallest relative cut of a cost that counts as an improvement.
MIN_RELATIVE_GAIN: Final = 0.01
#: Coarse thresholds closer than this factor to a fixed operator's are not tried again.
THRESHOLD_SEPARATION: Final = 1.5
#: Times the threshold grid is refined around the best one.
REFINEMENTS: Final = 4


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
        out = _play_states(ws, state, local0)
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
    return _play_states(ws, without, without.fit.local)


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
    steps = round(RESCAN_PERIODS / DELAY_STEP)
    grid = center + DELAY_STEP * np.arange(-steps, steps + 1)
    grid = grid[grid >= DELAY_STEP - 1e-9]
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
    """Scan command shifts with the current law, then refit around the best one.

    Whole command periods first (1 to ``MAX_DELAY_PERIODS``), then fractions of a period in
    steps of ``DELAY_STEP`` within a period either side of the best whole shift; the best
    fractional shift and its two neighbours are refitted.
    """
    period = ws.aligned.command_period
    thresholds = state.play_thresholds
    n_max = int(min(MAX_DELAY_PERIODS, max(1, MAX_DELAY_S / period)))
    play = None if thresholds is None else ws.play_pair(thresholds, state.delay_s)[0]

    def cost(periods: float) -> float:
        shifted = ws.inputs(ws.fit_rows, periods * period, play)
        pred = state.model.evaluate(state.fit.local, state.fit.glob, shifted, False).prediction
        return float(np.sum(np.where(shifted.valid, shifted.displacement - pred, 0.0) ** 2))

    whole = np.arange(1, n_max + 1, dtype=np.float64)
    best_j = float(whole[int(np.argmin([cost(j) for j in whole]))])
    steps = round(1.0 / DELAY_STEP)
    fine = best_j + DELAY_STEP * np.arange(-steps, steps + 1)
    fine = fine[(fine >= DELAY_STEP) & (fine <= n_max)]
    fine_costs = [cost(d) for d in fine]
    i = int(np.argmin(fine_costs))
    chosen = [float(fine[i])]
    if fine_costs[i] <= state.fit.total_cost:  # worth refitting the neighbours too
        chosen = [float(d) for d in fine[max(i - 1, 0) : i + 2]]
    out = []
    for d in chosen:
        train, held = ws.input_pair(d * period, thresholds)
        out.append(
            fit_state(
                model,
                train,
                held,
                local0,
                extend_global(state, model, {}),
                delay_s=d * period,
                thresholds=state.thresholds,
                max_iter=15,
            )
        )
    return out


def _play_states(ws: Workspace, state: ModelState, local0: FloatArray) -> list[ModelState]:
    """Fit 1 to ``max_order`` play operators; return the number the held-out BIC prefers.

    Operator k's threshold is scanned on a logarithmic grid of the command range with the
    other operators' thresholds fixed and zoomed in between the best one's neighbours; with
    two or more operators every threshold is then zoomed again with the others fixed (one
    coordinate pass). The weights are refitted jointly with the law at every trial (a new
    one started from 0). Operator k is kept only when it lowers the held-out BIC (effective
    sample count) and cuts the held-out RMS by ``MIN_RELATIVE_GAIN``.
    """
    span = float(np.ptp(ws.aligned.command[:, ws.actuators]))
    coarse = [max(f * span, 1e-6) for f in THRESHOLD_FRACTIONS]
    effect = with_role(Role.PLAY)
    assert effect is not None  # reached only for the PLAY candidate
    effects = (*state.model.effects, effect.name)
    first = {f"{effect.name}.{k}": v for k, v in effect.starts(0.0)[0].items()}
    best: ModelState | None = None
    for order in range(1, effect.max_order + 1):
        model = CompositeModel(effects, operators=order)
        base = state if best is None else best
        start = (local0 if best is None else best.fit.local, extend_global(base, model, first))
        fixed = () if best is None else best.thresholds
        free = [r for r in coarse if _apart(r, fixed)]
        if not free:
            break
        new = _trials(ws, state, model, start, [(*fixed, r) for r in free])
        if new.fit.total_cost > (1.0 - MIN_RELATIVE_GAIN) ** 2 * base.fit.total_cost:
            if best is None:
                return [new]  # no threshold helps even on training data: nothing to refine
            break
        i = free.index(new.thresholds[-1])
        new = _zoom(
            ws, state, new, order - 1, (free[max(i - 1, 0)], free[min(i + 1, len(free) - 1)])
        )
        for k in range(order if order > 1 else 0):
            r = new.thresholds[k]
            new = _zoom(ws, state, new, k, (r / THRESHOLD_SEPARATION, r * THRESHOLD_SEPARATION))
        train, held = ws.input_pair(state.delay_s, new.thresholds)
        new = fit_state(
            model,
            train,
            held,
            new.fit.local,
            new.fit.glob,
            delay_s=state.delay_s,
            thresholds=new.thresholds,
        )
        if best is not None and (
            effect.problem(effect_parameters(new, effect.name, ws.aligned)) is not None
            or not _operator_pays(ws, best, new)
        ):
            break  # a further operator must have physical weights and pay on held-out data
        best = new
    assert best is not None  # order 1 either returned early or set it
    return [best]


def _apart(r: float, others: Sequence[float]) -> bool:
    """Return whether threshold ``r`` is at least ``THRESHOLD_SEPARATION`` from ``others``."""
    return all(max(r / f, f / r) > THRESHOLD_SEPARATION for f in others)


def _zoom(
    ws: Workspace, state: ModelState, current: ModelState, k: int, bounds: tuple[float, float]
) -> ModelState:
    """Refine operator ``k``'s threshold within ``bounds``, the others fixed."""
    lo, hi = bounds
    for _ in range(REFINEMENTS):
        r_k = current.thresholds[k]
        others = current.thresholds[:k] + current.thresholds[k + 1 :]
        grid = sorted({*np.geomspace(lo, hi, FINE_THRESHOLDS + 2).tolist(), r_k})
        inner = [r for r in grid if r != r_k and lo < r < hi and _apart(r, others)]
        if not inner:
            break
        tuples = [(*current.thresholds[:k], r, *current.thresholds[k + 1 :]) for r in inner]
        trial = _trials(ws, state, current.model, (current.fit.local, current.fit.glob), tuples)
        current = trial if trial.fit.total_cost < current.fit.total_cost else current
        i = grid.index(current.thresholds[k])
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    return current


def _operator_pays(ws: Workspace, fewer: ModelState, more: ModelState) -> bool:
    """Return whether one more play operator (weight and threshold) pays on held-out data."""
    _, held = ws.input_pair(fewer.delay_s, fewer.play_thresholds)
    n_eff = effective_count(ws, fewer, held)
    delta = information_delta(fewer.heldout_sse, more.heldout_sse, n_eff, 2)
    gain = 1.0 - more.heldout_rms / max(fewer.heldout_rms, 1e-300)
    return delta < 0 and gain >= MIN_RELATIVE_GAIN


def _trials(
    ws: Workspace,
    state: ModelState,
    model: CompositeModel,
    start: tuple[FloatArray, FloatArray],
    tuples: Sequence[tuple[float, ...]],
) -> ModelState:
    """Fit the model at each tuple of play thresholds; return the best (one play pass)."""
    local0, glob0 = start
    unique = sorted({r for t in tuples for r in t})
    fit_play, score_play = ws.play_pair(unique, state.delay_s)
    trials = []
    for thresholds in tuples:
        pick = [unique.index(r) for r in thresholds]
        train = ws.inputs(ws.fit_rows, state.delay_s, fit_play[:, pick, :])
        held = ws.inputs(ws.score_rows, state.delay_s, score_play[:, pick, :])
        trials.append(
            fit_state(
                model,
                train,
                held,
                local0,
                glob0,
                delay_s=state.delay_s,
                thresholds=thresholds,
                max_iter=10,
            )
        )
    return min(trials, key=lambda s: s.fit.total_cost)
