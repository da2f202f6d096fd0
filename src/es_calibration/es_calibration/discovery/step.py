"""The discovery step: after the registry search, find library terms in its held-out residual.

Runs on the screening block (rows of at most ``MAX_ACTUATORS`` of its actuators, at most
``TRAIN_ROWS`` training and ``HELD_ROWS`` held-out rows each), only when the held-out RMS
stands above the noise floor by ``NOISE_RATIO_LIMIT`` (where the residual counts as unexplained)
and by the search's information criterion. Terms are fitted on the
training rows and chosen on the held-out ones (regression.py); the time constants of the
selected low-passes are then refined on the training rows. Every term's coefficient is
refitted on each half of the record (time order) for its stability. Where the terms leave
the held-out RMS above the floor, a slew-rate limit behind the drive is searched too (the
law refitted behind it, limit.py) and takes the terms' place where it explains more.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Final

import numpy as np

from es_calibration.data.align import AlignedData
from es_calibration.discovery.creep import CreepFit, search_creep
from es_calibration.discovery.exact import judged_exactly, library_for, refined_drive, slopes
from es_calibration.discovery.library import Library, LibraryTerm, Rows, columns, usable
from es_calibration.discovery.limit import LimitFit, search_rate_limit
from es_calibration.discovery.regression import Gram, select, stable
from es_calibration.discovery.terms import DiscoveredTerm, Discovery, FactorKey
from es_calibration.search.residual import integrated_autocorrelation_time
from es_calibration.search.state import (
    MIN_RELATIVE_GAIN,
    ModelState,
    Workspace,
    heldout_residual,
    information_delta,
)
from es_calibration.search.unexplained import NOISE_RATIO_LIMIT
from es_common.arrays import FloatArray, IndexArray
from es_physics.effects.discovered import CREEP, Carrier
from es_physics.effects.discovered import Term as PhysicsTerm

MAX_ACTUATORS: Final = 16
TRAIN_ROWS: Final = 1500
HELD_ROWS: Final = 3000
#: Samples per block of library columns built at once (bounds the step's memory).
CHUNK: Final = 4096
#: A term is searched only where at least this share of it (its training energy) is beyond
#: what the model's own unknowns describe (see _grams): the rest of such a term is the model's
#: and would shift its values by as much, making it a new term in name only.
MIN_DISTINCT: Final = 0.1
#: Relative ridge of the law's normal equations in the projection (see _grams).
RIDGE_LAW: Final = 1e-10
#: A refined time constant (a low-pass's, the creep's shortest) is tried at these factors of
#: the library's.
REFINE_FACTORS: Final = tuple(float(f) for f in np.geomspace(0.25, 4.0, 13))

Term = LibraryTerm


@dataclass
class _Sets:
    """The discovery's samples: signals, residual and which set each (actuator, row) is in."""

    signals: dict[FactorKey, FloatArray]
    residual: FloatArray  # (A, n)
    pick: tuple[IndexArray, IndexArray]  # usable (actuator, column of the row set)
    held: np.ndarray  # per picked sample: held-out (else training)
    late: np.ndarray  # per picked sample: in the record's second half
    library: Library
    at: Rows
    jac: FloatArray  # the model's Jacobian at the rows (A, n, P + G)

    def ensure(self, terms: list[Term]) -> None:
        """Compute the signals of factors not yet evaluated (e.g. a refined time constant)."""
        missing = list({k for _, factors in terms for k in factors if k not in self.signals})
        if missing:
            self.signals.update(self.library.signals(self.at, missing))


def _thin(rows: IndexArray, most: int) -> IndexArray:
    return rows[:: max(1, int(np.ceil(rows.size / most)))]


def _residual_rows(ws: Workspace, state: ModelState
                   ) -> tuple[Rows, float, int, FloatArray]:
    """Return the model's prediction and residual on thinned training + held-out rows.

    Also the effective number of independent held-out residuals per held-out sample kept and
    the number of training rows (they come first).
    """
    train_in, held_in = ws.input_pair(state.delay_s, state.play_thresholds)
    r_train = heldout_residual(state, train_in)
    r_held = heldout_residual(state, held_in)
    stride = max(1, int(np.median(np.diff(ws.score_rows))))
    tau = integrated_autocorrelation_time(r_held, np.diff(ws.score_rows) == stride)
    ti = _thin(np.arange(ws.fit_rows.size), TRAIN_ROWS)
    hi = _thin(np.arange(ws.score_rows.size), HELD_ROWS)
    thinning = max(1.0, ws.score_rows.size / max(hi.size, 1))
    rows = np.concatenate([ws.fit_rows[ti], ws.score_rows[hi]])
    resid = np.concatenate([r_train[:, ti], r_held[:, hi]], axis=1)
    disp = np.concatenate([train_in.displacement[:, ti], held_in.displacement[:, hi]], axis=1)
    held_share = 1.0 / max(tau / thinning, 1.0)
    parts, drive, temperature = [], [], []
    for inputs, idx in ((train_in, ti), (held_in, hi)):
        ev = state.model.evaluate(state.fit.local, state.fit.glob, inputs, jacobian=True)
        parts.append(np.concatenate([ev.jac_local[:, idx], ev.jac_global[:, idx]], axis=2))
        dz_dv, dz_dt = slopes(state, inputs)
        drive.append(dz_dv[:, idx])
        temperature.append(dz_dt[:, idx])
    jac = np.concatenate(parts, axis=1)
    at = Rows(rows, disp - np.nan_to_num(resid), resid, np.concatenate(drive, axis=1),
              np.concatenate(temperature, axis=1))
    return at, held_share, int(ti.size), jac


def _grams(sets: _Sets, terms: list[Term], scales: FloatArray | None
           ) -> tuple[dict[tuple[bool, bool], Gram], FloatArray, FloatArray]:
    """Return the Grams by (held-out, second half), the columns' scales and distinct shares.

    A column's distinct share: the part of its training energy the projection (below)
    leaves, i.e. what of the term the model's own unknowns cannot describe.

    The model's own unknowns would take up part of any new term in a joint fit: per
    actuator, the columns and the residual have their least-squares projection on the
    model's Jacobian (the law's coefficients and the effects' shared unknowns, the latter
    conservatively as if per actuator) over the training rows taken away (on the held-out
    rows, the same coefficients' prediction): a term is scored as if fitted jointly (so the
    model is refitted with the terms written, :func:`refit_with_terms`).
    """
    sets.ensure(terms)
    if scales is None:
        train = np.flatnonzero(~sets.held)[:CHUNK * 4]
        sample = columns(sets.signals, terms, (sets.pick[0][train], sets.pick[1][train]))
        scales = np.sqrt(np.mean(sample * sample, axis=0))
        scales = np.where(scales > 0, scales, 0.0)
    safe = np.where(scales > 0, scales, 1.0)
    grams = {(h, s): Gram.empty(len(terms)) for h in (False, True) for s in (False, True)}
    raw, left = np.zeros(len(terms)), np.zeros(len(terms))
    r = sets.residual[sets.pick]
    for actuator in np.unique(sets.pick[0]):
        sl = np.flatnonzero(sets.pick[0] == actuator)
        x = columns(sets.signals, terms, (sets.pick[0][sl], sets.pick[1][sl])) / safe
        x[:, scales == 0] = 0.0
        both = np.column_stack([x, r[sl]])
        fit = ~sets.held[sl]
        jac = np.nan_to_num(sets.jac[actuator, sets.pick[1][sl]])
        jt = jac[fit]
        normal = jt.T @ jt
        normal += RIDGE_LAW * np.trace(normal) / max(normal.shape[0], 1) * np.eye(normal.shape[0])
        raw += np.einsum("ij,ij->j", x[fit], x[fit])
        both = both - jac @ np.linalg.solve(normal, jt.T @ both[fit])
        left += np.einsum("ij,ij->j", both[fit, :-1], both[fit, :-1])
        for (h, s), gram in grams.items():
            mask = (sets.held[sl] == h) & (sets.late[sl] == s)
            if mask.any():
                gram.add(both[mask, :-1], both[mask, -1])
    return grams, scales, left / np.where(raw > 0, raw, np.inf)


def _split(grams: dict[tuple[bool, bool], Gram]) -> tuple[Gram, Gram, Gram, Gram]:
    """Return (training, held-out, first half, second half) Grams."""
    g = grams
    return (g[(False, False)] + g[(False, True)], g[(True, False)] + g[(True, True)],
            g[(False, False)] + g[(True, False)], g[(False, True)] + g[(True, True)])


def _refine(sets: _Sets, chosen: list[Term]) -> list[Term]:
    """Return ``chosen`` with each low-pass's time constant and each rate limit refined."""
    out = list(chosen)
    for i, (carrier, term) in enumerate(chosen):
        for f, (code, tau) in enumerate(term):
            if code not in (10, 11, CREEP) and not (code == 15 and tau > 0):
                continue
            best: tuple[float, Term] | None = None
            for factor in REFINE_FACTORS:
                factors = list(out[i][1])
                factors[f] = (code, tau * factor)
                candidate: Term = (carrier, tuple(factors))
                trial = [*out[:i], candidate, *out[i + 1:]]
                train, _, _, _ = _split(_grams(sets, trial, None)[0])
                idx = list(range(len(trial)))
                sse = train.sse(idx, train.solve(idx))
                if best is None or sse < best[0]:
                    best = (sse, candidate)
            if best is not None:
                out[i] = best[1]
    return out


def discover(aligned: AlignedData, grid: tuple[int, int], state: ModelState,
             noise_floor_m: float,
             placement: tuple[IndexArray, tuple[int, int]] | None = None) -> Discovery:
    """Search the library for terms the held-out residual of ``state`` still contains.

    Args:
        aligned: the screening block's record.
        grid: the block's shape (actuators row-major).
        state: the registry search's final model on the block.
        noise_floor_m: the measurement noise floor [m] (of the final residual).
        placement: the block's actuators as row-major indices of the whole grid, and that
            grid (default: the block is the grid).

    """
    clock = time.perf_counter()
    ws = Workspace(aligned, np.arange(aligned.n_actuators, dtype=np.intp), grid)
    at, held_share, n_train, jac = _residual_rows(ws, state)
    library = library_for(ws, state, None, placement)
    singles = library.keys()
    signals = library.signals(at, singles)
    A = aligned.n_actuators
    keep = np.unique(np.linspace(0, A - 1, min(A, MAX_ACTUATORS)).round().astype(np.intp))
    ok = usable(at.residual, signals)
    ok[np.setdiff1d(np.arange(A), keep)] = False
    rows_of, cols_of = np.nonzero(ok)
    pick = (rows_of, cols_of)
    held = pick[1] >= n_train
    t_mid = 0.5 * float(aligned.t[-1])
    late = aligned.t[at.rows][pick[1]] >= t_mid
    sets = _Sets(signals, at.residual, pick, held, late, library, at, jac)
    r_held = at.residual[pick][held]
    before = float(np.sqrt(np.mean(r_held**2))) if r_held.size else float("nan")
    n_eff = max(2.0, r_held.size * held_share)
    floor_sse = noise_floor_m**2 * r_held.size
    above = (np.isfinite(noise_floor_m) and np.isfinite(before)
             and before > NOISE_RATIO_LIMIT * noise_floor_m
             and information_delta(float(r_held @ r_held), floor_sse, n_eff, 1) < 0)
    if not above:
        return Discovery(False, heldout_rms_before_m=before, heldout_rms_after_m=before,
                         note="the held-out residual is at the noise floor: no term searched",
                         seconds=time.perf_counter() - clock)
    terms = library.terms(singles)
    grams, _scales, distinct = _grams(sets, terms, None)
    train, held_gram, _, _ = _split(grams)
    own = distinct >= MIN_DISTINCT  # what the model's unknowns describe is not a new term
    chosen = _refine(sets, [terms[j] for j in select(train, held_gram, n_eff,
                                                      allowed=own).chosen])
    if all(_usable(t) for t in chosen):
        writable = chosen
    else:  # the model gets the best set the feedforward can undo (or metrology), chosen alike
        allowed = own & np.array([_usable(t) for t in terms])
        writable = _refine(sets, [terms[j] for j in select(
            train, held_gram, n_eff, allowed=allowed).chosen])
    result = _terms(sets, chosen, writable)
    result.library_size = len(terms)
    if result.added:
        result = judged_exactly(ws, state, refined_drive(ws, state, result, placement),
                                 placement)
    for search in (search_rate_limit, search_creep):
        if not (result.added
                and result.heldout_rms_after_m <= NOISE_RATIO_LIMIT * noise_floor_m):
            result = _with_search(result, search(ws, state))
    result.seconds = time.perf_counter() - clock
    return result


def _with_search(linear: Discovery, found: LimitFit | CreepFit | None) -> Discovery:
    """Return ``linear``, or a search's term where it explains more (limit.py, creep.py).

    The search's term wins when accepted and its held-out RMS after, relative to before, is
    lower than the library terms' (each on its own rows); the library's terms stay reported.
    """
    if found is None or not found.accepted:
        return linear
    ratio = found.heldout_rms_after_m / found.heldout_rms_before_m
    if linear.added and linear.heldout_rms_after_m / linear.heldout_rms_before_m <= ratio:
        return linear
    return found.discovery(linear)


def _usable(term: Term) -> bool:
    """Return whether the model may take ``term``.

    It may when the feedforward can undo it (es_physics' rule) or when it acts on the
    measurement (the feedforward has nothing to undo).
    """
    carrier, factors = term
    return carrier is Carrier.MEASUREMENT or PhysicsTerm(
        1.0, factors[0], factors[1] if len(factors) > 1 else None, carrier).compensable


def _describe(sets: _Sets, chosen: list[Term]) -> tuple[list[DiscoveredTerm], list[float], int]:
    """Fit ``chosen`` jointly on the training rows and describe each term (see _grams).

    Returns the terms (coefficient, share of the held-out error it removed in order, halves,
    stability), the held-out SSE before any and after each, and the held-out count.
    """
    grams, scales, _ = _grams(sets, chosen, None)
    train, held, first, second = _split(grams)
    idx = list(range(len(chosen)))
    beta = train.solve(idx)
    path = [held.rr] + [held.sse(idx[: k + 1], train.solve(idx[: k + 1])) for k in idx]
    halves = (first.solve(idx) / scales, second.solve(idx) / scales)
    found = []
    for k, (carrier, factors) in enumerate(chosen):
        coefficient = float(beta[k] / scales[k])
        pair = (float(halves[0][k]), float(halves[1][k]))
        found.append(DiscoveredTerm(
            "", factors, coefficient, float((path[k] - path[k + 1]) / max(path[0], 1e-300)),
            pair, stable(coefficient, pair), carrier,
        ))
    return found, path, held.count


def _terms(sets: _Sets, chosen: list[Term], writable: list[Term]) -> Discovery:
    """Describe the selected terms; choose what the parameters file gets.

    ``chosen``: the selection from the whole library (what the residual holds, reported);
    ``writable``: the selection among the terms the model may take (:func:`_usable`; the
    same when every chosen term is one). Its stable terms, refitted alone (and still
    stable), are used; their description replaces ``chosen``'s, the others follow
    ``chosen``'s. All RMS are as if the model were refitted with the terms (see _grams).
    """
    if not chosen:
        before = float(np.sqrt(np.mean(sets.residual[sets.pick][sets.held] ** 2)))
        return Discovery(True, heldout_rms_before_m=before, heldout_rms_after_m=before,
                         note="no term of the library generalises to the held-out blocks: "
                              "nothing added")
    found, path, count = _describe(sets, chosen)
    before = float(np.sqrt(path[0] / max(count, 1)))  # with the law refitted alike
    every = float(np.sqrt(path[-1] / max(count, 1)))
    described, described_path = (
        (found, path) if writable == chosen
        else _describe(sets, writable)[:2] if writable else ([], []))
    kept = [(t.acts_on, t.factors) for t in described if t.stable]
    used: list[DiscoveredTerm] = []
    after = before
    while kept:  # refitted alone, a term may lose its stability: refit without it
        refit, kept_path = (
            (described, described_path) if len(kept) == len(described)  # all: the same fit
            else _describe(sets, kept)[:2])
        still = [(t.acts_on, t.factors) for t in refit if t.stable]
        if len(still) == len(kept):
            used = [replace(t, used=True) for t in refit]
            after = float(np.sqrt(kept_path[-1] / max(count, 1)))
            break
        kept = still
    added = bool(used) and after < (1.0 - MIN_RELATIVE_GAIN) * before
    by_term = {(t.acts_on, t.factors): t for t in used} if added else {}
    terms = [by_term.pop((t.acts_on, t.factors), t) for t in found] + list(by_term.values())
    terms = [replace(t, name=f"discovered_{k}") for k, t in enumerate(terms, start=1)]
    note = "" if added else (
        "the discovered terms are not stable on both halves of the record or the feedforward "
        "cannot undo them: reported, not added"
    )
    return Discovery(True, terms, added, before, after if added else before, note,
                     heldout_rms_all_terms_m=every)
