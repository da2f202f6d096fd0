"""How the play (Prandtl-Ishlinskii) candidate is fitted on top of a model state.

The thresholds are screened at once on a logarithmic grid of the command's range: with the
model linearised at the current state, each operator's weight enters the displacement
linearly, dz ~ dz/dV a(T) w_i (play_(r_i)(V) - V), and the per-actuator law can move too
(its columns are projected out actuator by actuator, a Schur complement, so no loop over
actuators). The non-negative weights of every subset of 1 .. ``max_order`` grid thresholds
come from NNLS (:func:`es_physics.effects.hysteresis.best_operators`); the best subset of
each size is zoomed in around its thresholds the same way, then the weights are refitted
jointly with the law and the other effects (Levenberg-Marquardt, starting at the NNLS
weights). The number of operators is the largest whose extra operator lowers the held-out
information criterion and keeps all weights physical.
"""

from __future__ import annotations

from dataclasses import replace
from itertools import combinations
from typing import Final

import numpy as np
from scipy.optimize import nnls

from es_calibration.errors import CalibrationFitError
from es_calibration.model.composite import CompositeModel, FitInputs
from es_calibration.model.fit import pooled_gram
from es_calibration.search.state import (
    MIN_RELATIVE_GAIN,
    ModelState,
    Workspace,
    effect_parameters,
    effective_count,
    extend_global,
    fit_state,
    information_delta,
)
from es_common.arrays import FloatArray
from es_physics.effects import Effect, Role, with_role
from es_physics.effects.hysteresis import MAX_OPERATORS

#: Thresholds screened at once, as fractions of the command's range (low, high, count).
THRESHOLD_GRID: Final = (0.004, 0.35, 28)
#: Thresholds tried per operator in one zoom level, and zoom levels.
ZOOM_POINTS: Final = 9
ZOOM_LEVELS: Final = 2
#: Most (samples x actuators x thresholds) values of one linearised screening.
SCREEN_BUDGET: Final = 6_000_000

NormalEquations = tuple[FloatArray, FloatArray]


def nonnegative_weights(gram: FloatArray, rhs: FloatArray) -> tuple[FloatArray, float]:
    """Return the weights w >= 0 minimising w' G w - 2 b' w, and that minimum.

    ``gram`` (K, K) and ``rhs`` (K,) are the normal equations of a least-squares problem
    ||C w - r||^2 = ||r||^2 + w' G w - 2 b' w (G = C'C, b = C'r, any units): the minimum is
    the change of the sum of squares the weights bring (<= 0). Solved as the equivalent
    K x K non-negative least-squares problem ||R w - R^-T b|| (G = R'R) with scipy's NNLS,
    so the weights are non-negative by construction.

    Raises:
        CalibrationFitError: shapes that do not match or values that are not finite.

    """
    G = np.asarray(gram, np.float64)
    b = np.asarray(rhs, np.float64)
    K = b.size
    if G.shape != (K, K) or K == 0:
        raise CalibrationFitError(f"gram {G.shape} does not match rhs ({K},)")
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(b))):
        raise CalibrationFitError("normal equations of the play weights are not finite")
    scale = np.sqrt(np.maximum(np.diag(G), 1e-300))
    Gs = G / np.outer(scale, scale) + 1e-10 * np.eye(K)
    R = np.linalg.cholesky(Gs).T  # Gs = R'R
    d = np.linalg.solve(R.T, b / scale)
    ws, _ = nnls(R, d)
    w = ws / scale
    return np.asarray(w, np.float64), float(w @ G @ w - 2.0 * b @ w)


def best_operators(
    gram: FloatArray, rhs: FloatArray, max_order: int = MAX_OPERATORS
) -> list[tuple[tuple[int, ...], FloatArray, float]]:
    """Return, for N = 1 .. ``max_order``, the N columns whose NNLS fit is best.

    ``gram`` and ``rhs`` are the normal equations over K candidate operators (e.g. a grid of
    thresholds, see :func:`nonnegative_weights`). Every subset of N columns is tried; a
    subset where NNLS zeroes a weight is a smaller one in disguise and is skipped. Each entry
    is (column indices, their weights >= 0, change of the sum of squares); an N no subset
    reaches with all weights positive is left out.

    Raises:
        CalibrationFitError: as :func:`nonnegative_weights`.

    """
    K = np.asarray(rhs).size
    out: list[tuple[tuple[int, ...], FloatArray, float]] = []
    for order in range(1, min(max_order, K) + 1):
        best: tuple[tuple[int, ...], FloatArray, float] | None = None
        for subset in combinations(range(K), order):
            idx = list(subset)
            w, change = nonnegative_weights(gram[np.ix_(idx, idx)], rhs[idx])
            if np.all(w > 0) and (best is None or change < best[2]):
                best = (subset, w, change)
        if best is not None:
            out.append(best)
    return out


def _play_effect() -> Effect:
    effect = with_role(Role.PLAY)
    if effect is None:  # only reached for a registered PLAY candidate
        raise LookupError("no effect with the play role is registered")
    return effect


def _temperature_name(effect: Effect, order: int) -> str:
    """Return the play effect's temperature-law parameter (after the ``order`` weights)."""
    return effect.fit_names(order)[order]


def _current_play(state: ModelState, inputs: FitInputs) -> tuple[FloatArray, FloatArray]:
    """Return a sum_i w_i and a sum_i w_i (play_i - V), (A, n) each, of ``state``'s operators.

    ``a`` is the weights' temperature factor; both are 0 without a play effect.
    """
    model = state.model
    zero = np.zeros_like(inputs.voltage)
    if model.play is None or inputs.play is None:
        return zero, zero
    names = model.global_names
    order = model.operators
    g = state.fit.glob
    w = [float(g[names.index(model.key(model.play, i))]) for i in range(order)]
    beta = float(g[names.index(model.key(model.play, order))])
    a = np.exp(-beta * (inputs.temperature - inputs.mean_temperature))
    mix = np.einsum("k,kan->an", np.asarray(w), inputs.play - inputs.voltage[None])
    return a * sum(w), a * mix


def normal_equations(
    ws: Workspace, state: ModelState, thresholds: FloatArray, betas: tuple[float, ...]
) -> list[NormalEquations]:
    """Return the weights' normal equations (G (K, K), b (K,)) at ``state``, one per beta.

    Gauss-Newton at ``state``: the columns are dz/dV_eff exp(-beta (T - T_mean))
    (play_(r_k)(V) - V) on a subsample of the training rows, each actuator's law coefficients
    projected out. A play effect already in ``state`` is taken out of the target (to first
    order), so the weights solved for replace its weights: the NNLS is a new allocation of
    the whole operator over ``thresholds``.
    """
    A = len(ws.actuators)
    K = len(thresholds)
    rows = ws.sub_rows(max(1, -(-ws.fit_rows.size * A * K // SCREEN_BUDGET)))
    command_rows = ws.aligned.command_index(rows, state.delay_s)
    now = ws.cached_play(list(state.thresholds), command_rows) if state.model.play else None
    inputs = ws.inputs(rows, state.delay_s, now)
    model, local, glob = state.model, state.fit.local, state.fit.glob
    ev = model.evaluate(local, glob, inputs, jacobian=True)
    span = max(float(np.ptp(inputs.voltage)), 1e-6)
    step = 1e-3 * span
    up = model.evaluate(local, glob, replace(inputs, voltage=inputs.voltage + step), False)
    down = model.evaluate(local, glob, replace(inputs, voltage=inputs.voltage - step), False)
    play = ws.cached_play(thresholds.tolist(), command_rows)  # (n, K, A)
    gaps = np.transpose(play, (2, 0, 1)) - inputs.voltage[..., None]  # (A, n, K)
    valid = inputs.valid & np.isfinite(gaps).all(axis=2)
    gaps = np.where(valid[..., None], gaps, 0.0)
    weight_now, mix_now = _current_play(state, inputs)
    # d z / d V_eff: the finite difference moved V with the play outputs held
    slope = (up.prediction - down.prediction) / (2.0 * step) / np.maximum(1.0 - weight_now, 0.05)
    slope = np.where(valid, slope, 0.0)
    resid = np.where(valid, inputs.displacement - ev.prediction + slope * mix_now, 0.0)
    J = np.where(valid[..., None], ev.jac_local, 0.0)  # (A, n, P)
    U = np.swapaxes(J, 1, 2) @ J
    # a ridge relative to each actuator's scale; an actuator with no valid row has U = 0
    scale = np.einsum("app->ap", U).max(axis=1)
    ridge = np.where(scale > 0.0, 1e-10 * scale, 1.0)
    U = U + ridge[:, None, None] * np.eye(U.shape[1])
    dT = inputs.temperature - inputs.mean_temperature
    bl = np.einsum("anp,an->ap", J, resid)
    Ui_bl = np.linalg.solve(U, bl[..., None])[..., 0]
    out: list[NormalEquations] = []
    for beta in betas:
        C = (slope * np.exp(-beta * dT))[..., None] * gaps
        W = np.swapaxes(J, 1, 2) @ C  # (A, P, K)
        Ui_W = np.linalg.solve(U, W)
        CC, Cr = pooled_gram(C, resid)
        G = CC - np.einsum("apk,apl->kl", W, Ui_W)
        b = Cr - np.einsum("apk,ap->k", W, Ui_bl)
        out.append((0.5 * (G + G.T), b))
    return out


def _zoom(
    ws: Workspace, state: ModelState, thresholds: tuple[float, ...], beta: float, ratio: float
) -> tuple[float, ...]:
    """Refine each threshold within a factor ``ratio`` of it, the others fixed (linearised)."""
    current = list(thresholds)
    for _ in range(ZOOM_LEVELS):
        offsets = ratio ** np.linspace(-1.0, 1.0, ZOOM_POINTS)
        trial = sorted({*current, *(float(r * o) for r in current for o in offsets)})
        G, b = normal_equations(ws, state, np.array(trial), (beta,))[0]
        for k in range(len(current)):
            best: tuple[float, float] | None = None
            for o in offsets:
                cand = [*current[:k], float(current[k] * o), *current[k + 1 :]]
                idx = [trial.index(r) for r in cand]
                if len(set(idx)) < len(idx):
                    continue
                w, change = nonnegative_weights(G[np.ix_(idx, idx)], b[idx])
                if np.all(w > 0) and (best is None or change < best[0]):
                    best = (change, cand[k])
            if best is not None:
                current[k] = best[1]
        ratio = ratio ** (2.0 / (ZOOM_POINTS - 1))
    return tuple(current)


def _screen(
    ws: Workspace, state: ModelState, grid: FloatArray, betas: tuple[float, ...], order: int
) -> tuple[tuple[float, ...], float] | None:
    """Return the best ``order`` grid thresholds (sorted) and beta at ``state``, or None."""
    found = []
    for (G, b), beta in zip(normal_equations(ws, state, grid, betas), betas, strict=True):
        choice = best_operators(G, b, order)
        if len(choice) == order:
            found.append((choice[-1], beta))
    if not found:
        return None
    (subset, _, _), beta = min(found, key=lambda f: f[0][2])
    return tuple(sorted(float(grid[i]) for i in subset)), beta


def _fit_operators(
    ws: Workspace,
    state: ModelState,
    at: ModelState,
    thresholds: tuple[float, ...],
    beta: float,
    *,
    local0: FloatArray,
) -> ModelState:
    """Fit ``state`` plus operators at ``thresholds`` (NNLS weights at ``at`` as the start)."""
    effect = _play_effect()
    G, b = normal_equations(ws, at, np.array(thresholds), (beta,))[0]
    weights, _ = nonnegative_weights(G, b)
    model = CompositeModel((*state.model.effects, effect.name), operators=len(thresholds))
    names = model.parameter_names(effect)
    start = {f"{effect.name}.{n}": float(w) for n, w in zip(names, weights, strict=False)}
    start[f"{effect.name}.{_temperature_name(effect, len(thresholds))}"] = beta
    train, held = ws.input_pair(state.delay_s, thresholds)
    return fit_state(
        model,
        train,
        held,
        at.fit.local if at.model.play else local0,
        extend_global(state, model, start),
        delay_s=state.delay_s,
        thresholds=thresholds,
    )


def play_states(ws: Workspace, state: ModelState, local0: FloatArray) -> list[ModelState]:
    """Fit 1 to ``max_order`` play operators on top of ``state``; return the one chosen.

    For each N: screen the grid at ``state`` (NNLS over every N-subset), fit; screen again
    at that fit (now linearised with the operator in place), zoom each threshold, fit. N is
    kept only when its last operator lowers the held-out BIC (effective sample count) and
    cuts the held-out RMS by ``MIN_RELATIVE_GAIN``, with every weight physical.
    """
    effect = _play_effect()
    span = float(np.ptp(ws.aligned.command[:, ws.actuators]))
    low, high, count = THRESHOLD_GRID
    grid = np.geomspace(max(low * span, 1e-6), max(high * span, 2e-6), count)
    ratio = float(grid[1] / grid[0])
    start_beta = float(effect.starts(0.0)[0].get(_temperature_name(effect, 1), 0.0))
    betas = tuple(sorted({0.0, start_beta}))
    best: ModelState | None = None
    for order in range(1, effect.max_order + 1):
        at = state if best is None else best
        first = _screen(ws, at, grid, betas, order)
        if first is None:
            break
        new = _fit_operators(ws, state, at, *first, local0=local0)
        again = _screen(ws, new, np.union1d(grid, new.thresholds), betas, order)
        if again is not None:
            thresholds = _zoom(ws, new, again[0], again[1], ratio)
            refined = _fit_operators(ws, state, new, thresholds, again[1], local0=local0)
            if refined.fit.total_cost < new.fit.total_cost:
                new = refined
        if effect.problem(effect_parameters(new, effect.name, ws.aligned)) is not None:
            if best is None:
                best = new  # one operator: the verdict on it is the search's
            break
        if best is not None and not _operator_pays(ws, best, new):
            break
        best = new
    if best is None:
        # no subset of the grid gets a positive weight: report one operator at the middle
        model = CompositeModel((*state.model.effects, effect.name), operators=1)
        r = (float(grid[count // 2]),)
        train, held = ws.input_pair(state.delay_s, r)
        best = fit_state(
            model,
            train,
            held,
            local0,
            extend_global(state, model, {}),
            delay_s=state.delay_s,
            thresholds=r,
        )
    return [best]


def _operator_pays(ws: Workspace, fewer: ModelState, more: ModelState) -> bool:
    """Return whether one more play operator (weight and threshold) pays on held-out data."""
    _, held = ws.input_pair(fewer.delay_s, fewer.play_thresholds)
    n_eff = effective_count(ws, fewer, held)
    delta = information_delta(fewer.heldout_sse, more.heldout_sse, n_eff, 2)
    gain = 1.0 - more.heldout_rms / max(fewer.heldout_rms, 1e-300)
    return delta < 0 and gain >= MIN_RELATIVE_GAIN


def without_weakest_operator(ws: Workspace, state: ModelState) -> ModelState | None:
    """Return ``state`` refitted without its least weighted play operator, or None.

    A refit with an effect added later (a drift, a coupling) can take over what an extra
    operator explained, leaving its weight at or below zero: that operator, not the whole
    play effect, is then what the data no longer support. None when ``state`` has no play
    effect or only one operator.
    """
    model = state.model
    play = model.play
    if play is None or model.operators < 2:
        return None
    order = model.operators
    old = dict(zip(model.global_names, state.fit.glob, strict=True))
    weakest = int(np.argmin([old[model.key(play, i)] for i in range(order)]))
    kept = [i for i in range(order) if i != weakest]
    reduced = CompositeModel(model.effects, operators=order - 1, per_actuator=model.per_actuator)
    start = {reduced.key(play, j): old[model.key(play, i)] for j, i in enumerate(kept)}
    start[reduced.key(play, order - 1)] = old[model.key(play, order)]  # the temperature law
    thresholds = tuple(state.thresholds[i] for i in kept)
    train, held = ws.input_pair(state.delay_s, thresholds)
    return fit_state(
        reduced,
        train,
        held,
        state.fit.local,
        np.array([start.get(n, old.get(n, 0.0)) for n in reduced.global_names], np.float64),
        delay_s=state.delay_s,
        thresholds=thresholds,
    )
