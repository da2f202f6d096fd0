"""Discovered terms taken out of the data as the feedforward undoes them, and the refits.

The step (step.py) selects terms through the model's sensitivities; the parameters file
carries the law refitted with the terms, and the feedforward undoes a drive term exactly
(the command solved so that V plus the terms is the voltage the law asks for). Here: the
model's sensitivities (:func:`slopes`), a term's displacement through them
(:func:`term_displacement`), the data with the terms taken out (:func:`moved_inputs`: a drive
term moves the voltage, a slew-rate limit through the limiter, the others the displacement),
the refit on it (:func:`refit_with_terms`), and the drive terms refined and judged that way
(:func:`refined_drive`, :func:`judged_exactly`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Final

import numpy as np
from scipy.optimize import minimize

from es_calibration.discovery.library import (
    Library,
    Rows,
    columns,
    displacement_series,
)
from es_calibration.discovery.limit import (
    behind_limit,
    limit_terms,
    rate_limited_command,
    rms,
)
from es_calibration.discovery.terms import DiscoveredTerm, Discovery
from es_calibration.model.composite import FitInputs
from es_calibration.search.state import (
    MIN_RELATIVE_GAIN,
    ModelState,
    Workspace,
    heldout_residual,
    refit_state,
)
from es_common.arrays import FloatArray, IndexArray
from es_physics.effects.discovered import CREEP, Carrier

#: Steps of the model's sensitivities to the drive [V] and the temperature [degC] (central
#: differences; the law is smooth on far larger scales).
SLOPE_STEP_V: Final = 0.1
SLOPE_STEP_DEGC: Final = 0.1
#: The drive terms' refinement (see refined_drive): refits at most, and the simplex's first
#: step in the log of each scale and limit.
DRIVE_REFINE_EVALUATIONS: Final = 40
DRIVE_REFINE_STEP: Final = 0.2


def slopes(state: ModelState, inputs: FitInputs) -> tuple[FloatArray, FloatArray]:
    """Return the model's dz/dV [m/V] and dz/dT [m/degC] at ``inputs`` (A, n).

    The command and the temperature move alone (a play operator's or a filtered drive's
    share of dz/dV is left out: a term on the drive is scored through the law's slope).
    """
    def at(moved: FitInputs) -> FloatArray:
        return state.model.evaluate(state.fit.local, state.fit.glob, moved,
                                    jacobian=False).prediction

    dv, dt = SLOPE_STEP_V, SLOPE_STEP_DEGC
    V, T = inputs.voltage, inputs.temperature
    drive = (at(replace(inputs, voltage=V + dv)) - at(replace(inputs, voltage=V - dv))) / (2 * dv)
    temperature = (at(replace(inputs, temperature=T + dt))
                   - at(replace(inputs, temperature=T - dt))) / (2 * dt)
    return drive, temperature


def modelled_displacement(ws: Workspace, state: ModelState) -> FloatArray:
    """Return ``state``'s displacement at every command of ``ws``'s block (Nc, A) [m].

    From its prediction on the training and held-out rows (:func:`displacement_series`):
    what the low-passes of the modelled displacement filter.
    """
    train, held = ws.input_pair(state.delay_s, state.play_thresholds)
    predicted = [state.model.evaluate(state.fit.local, state.fit.glob, i, jacobian=False
                                      ).prediction for i in (train, held)]
    rows = np.concatenate([ws.fit_rows, ws.score_rows])
    return displacement_series(ws.aligned, rows, np.concatenate(predicted, axis=1))


def library_for(ws: Workspace, state: ModelState, terms: list[DiscoveredTerm] | None,
                placement: tuple[IndexArray, tuple[int, int]] | None) -> Library:
    """Return the block's library, with the model's displacement where ``terms`` need it.

    ``terms`` None: the whole library (the displacement's low-passes included).
    """
    needs = terms is None or any(c == CREEP for t in terms for c, _ in t.factors)
    return Library(ws.aligned, ws.grid, placement=placement,
                   displacement=modelled_displacement(ws, state) if needs else None)


def term_displacement(library: Library, state: ModelState, inputs: FitInputs,
                      rows: IndexArray, terms: list[DiscoveredTerm]) -> FloatArray:
    """Return the displacement (A, n) [m] the ``terms`` add at ``rows`` (model ``inputs``).

    Drive and temperature terms through the model's sensitivities there, as the step fits
    them; a non-finite value counts as 0.
    """
    prediction = state.model.evaluate(state.fit.local, state.fit.glob, inputs,
                                      jacobian=False).prediction
    drive, temperature = slopes(state, inputs)
    at = Rows(rows, prediction, np.zeros_like(prediction), drive, temperature)
    signals = library.signals(at, list({k for t in terms for k in t.factors}))
    A, n = prediction.shape
    pick = (np.repeat(np.arange(A), n), np.tile(np.arange(n), A))
    values = columns(signals, [(t.acts_on, t.factors) for t in terms], pick)
    total = (values @ np.array([t.coefficient for t in terms])).reshape(A, n)
    return np.asarray(np.where(np.isfinite(total), total, 0.0), np.float64)


def _drive_values(library: Library, inputs: FitInputs, rows: IndexArray,
                  terms: list[DiscoveredTerm]) -> FloatArray:
    """Return what the drive ``terms`` add to the voltage (A, n) [V] at ``rows``."""
    A, n = inputs.voltage.shape
    zeros = np.zeros((A, n))
    signals = library.signals(Rows(rows, zeros, zeros, zeros, zeros),
                              list({k for t in terms for k in t.factors}))
    total = np.zeros((A, n))
    for t in terms:
        value = t.coefficient * signals[t.factors[0]]
        total += value * signals[t.factors[1]] if len(t.factors) > 1 else value
    return np.asarray(np.where(np.isfinite(total), total, 0.0), np.float64)


def moved_inputs(ws: Workspace, state: ModelState, terms: list[DiscoveredTerm],
                 placement: tuple[IndexArray, tuple[int, int]] | None = None,
                 library: Library | None = None) -> tuple[FitInputs, FitInputs]:
    """Return ``ws``'s (training, held-out) inputs with ``terms`` taken out of the data.

    A drive term moves the voltage as the feedforward undoes it (exactly: V plus the terms,
    a slew-rate limit as the command through the limiter, limit.py); the others move the
    displacement (temperature terms through the model's dz/dT, as the step fits them).
    ``library``: the block's, built for ``state`` (:func:`library_for`), where a search
    moves the data many times (default: built here).
    """
    if library is None:
        library = library_for(ws, state, terms, placement)
    train, held = ws.input_pair(state.delay_s, state.play_thresholds)
    pairs = [(train, ws.fit_rows), (held, ws.score_rows)]
    limits = limit_terms(terms)
    if limits:
        limited = rate_limited_command(ws.aligned, limits[0].factors[0][1])
        pairs = [(behind_limit(ws.aligned, i, rows, limited), rows) for i, rows in pairs]
    drive = [t for t in terms if t.acts_on is Carrier.DRIVE and t not in limits]
    if drive:
        pairs = [(replace(i, voltage=i.voltage + _drive_values(library, i, rows, drive)), rows)
                 for i, rows in pairs]
    others = [t for t in terms if t.acts_on is not Carrier.DRIVE]
    if others:
        pairs = [(replace(i, displacement=i.displacement - term_displacement(
            library, state, i, rows, others)), rows) for i, rows in pairs]
    return pairs[0][0], pairs[1][0]


def refit_with_terms(ws: Workspace, state: ModelState, discovery: Discovery,
                     placement: tuple[IndexArray, tuple[int, int]] | None = None
                     ) -> ModelState:
    """Return ``state`` refitted on ``ws`` with the terms used taken out of the data.

    The step scores a term as if fitted jointly with the model (its coefficients would take
    up part of it otherwise); the parameters file carries both, so the model's values must
    be those of that joint fit: the same model refitted on the data without the terms
    (:func:`moved_inputs`). ``ws`` holds the grid's actuators (the block is the grid).
    """
    if not discovery.used:
        return state
    train, held = moved_inputs(ws, state, discovery.used, placement)
    return refit_state(state, train, held)


def refined_drive(ws: Workspace, state: ModelState, result: Discovery,
                   placement: tuple[IndexArray, tuple[int, int]] | None) -> Discovery:
    """Return ``result`` with its drive terms' coefficients and rate limits refined.

    The selection fits a drive term through the law's slope; undone exactly (V plus the
    terms) with the law refitted, a slightly different coefficient and limit of |dV/dt| fit
    better (an amplifier's droop: 2.0 x the true noise through the slope, 1.2 x with its true
    values). Each rate limit starts from the best of the library's limits and none, then a
    simplex search over each drive term's log scale and each rate limit's log, at most
    ``DRIVE_REFINE_EVALUATIONS`` refits, all scored on the training rows; a limit at or
    above the record's fastest rate is none (0).
    """
    drive = [t for t in result.used if t.acts_on is Carrier.DRIVE and not limit_terms([t])]
    command = np.nan_to_num(ws.aligned.command)
    fastest = float(np.max(np.abs(np.diff(command, axis=0)), initial=0.0)
                    ) / ws.aligned.command_period
    limits = [(k, f) for k, t in enumerate(drive) for f, (code, _) in enumerate(t.factors)
              if code == 15]
    if not drive or fastest <= 0.0:
        return result

    def terms_at(x: FloatArray) -> list[DiscoveredTerm]:
        out = [replace(t, coefficient=t.coefficient * float(np.exp(x[k])))
               for k, t in enumerate(drive)]
        for j, (k, f) in enumerate(limits):
            limit = float(np.exp(x[len(drive) + j]))
            factors = list(out[k].factors)
            factors[f] = (15, 0.0 if limit >= fastest else limit)
            out[k] = replace(out[k], factors=tuple(factors))
        return out

    others = [t for t in result.used if t not in drive]

    def training_rms(x: FloatArray) -> float:
        train, held = moved_inputs(ws, state, others + terms_at(x), placement)
        new = refit_state(state, train, held)
        return rms(heldout_residual(new, train))

    start = np.array([0.0] * len(drive) + [
        float(np.log(drive[k].factors[f][1] or fastest)) for k, f in limits])
    baseline = training_rms(start)
    rate = np.abs(np.diff(command, axis=0)).ravel() / ws.aligned.command_period
    for j, (k, _) in enumerate(limits):  # each limit starts from the best of the library's
        for limit in Library(ws.aligned, ws.grid, placement=placement).rate_limits():
            trial = start.copy()
            trial[len(drive) + j] = np.log(limit)
            # the same mean term at that limit: a lower limit takes a larger coefficient
            trial[k] += np.log(np.mean(rate) / max(float(np.mean(np.minimum(rate, limit))),
                                                   1e-300))
            score = training_rms(trial)
            if score < baseline:
                start, baseline = trial, score
    simplex = np.vstack([start, start + DRIVE_REFINE_STEP * np.eye(start.size)])
    found = minimize(training_rms, start, method="Nelder-Mead", options={
        "maxfev": DRIVE_REFINE_EVALUATIONS, "initial_simplex": simplex, "xatol": 0.01,
        "fatol": 0.0})
    if not found.fun < baseline:
        return result
    by_name = {t.name: t for t in terms_at(found.x)}
    return replace(result, terms=[by_name.get(t.name, t) for t in result.terms])


def judged_exactly(ws: Workspace, state: ModelState, result: Discovery,
                    placement: tuple[IndexArray, tuple[int, int]] | None) -> Discovery:
    """Return ``result`` with its RMS before, after and with every term taken exactly.

    The selection scores the terms on thinned rows with the law's unknowns projected out, a
    drive term through the law's slope; the parameters file carries the law refitted with
    the terms and the feedforward undoes a drive term exactly (V plus the terms), so the
    terms are judged that way: the law refitted on the data with the terms taken out
    (:func:`moved_inputs`), every held-out row of the block. On the independent stand's
    amplifier droop: 1.06 nm through the slope; on its thermal gradient (4 x 4), 1.18 nm
    projected, 0.807 nm refitted, as the whole grid's 0.804 nm (docs/calibration.md).
    """
    def refitted_rms(terms: list[DiscoveredTerm]) -> float:
        train, held = moved_inputs(ws, state, terms, placement)
        new = refit_state(state, train, held)
        return rms(heldout_residual(new, held))

    plain = ws.input_pair(state.delay_s, state.play_thresholds)[1]
    before = rms(heldout_residual(state, plain))
    after = refitted_rms(result.used)
    if after < (1.0 - MIN_RELATIVE_GAIN) * before:
        every = after if len(result.terms) == len(result.used) else refitted_rms(result.terms)
        return replace(result, heldout_rms_before_m=before, heldout_rms_after_m=after,
                       heldout_rms_all_terms_m=every)
    return replace(result, added=False, heldout_rms_after_m=result.heldout_rms_before_m,
                   note="the drive terms, undone exactly with the law refitted, do not cut "
                        "the held-out error: reported, not added")
