"""The discovery's slew-rate limit: the law refitted behind a rate limiter on the drive.

An amplifier that cannot follow its command faster than r [V/s] is no small term: while it
slews, its output is off by up to a whole step (tens of volts, often across 0 V where the
electrostrictive law is flat), so a term fitted through the law's slope dz/dV, as the
library's drive terms are, takes the wrong size and even the wrong sign (measured on a stand
whose only unlisted effect was a 5,422 V/s limit: a coefficient of -0.21 for what is 1, and
the held-out error 27 x the noise). And a law fitted on slewed data is itself off, by 10 to
14 % at mid voltages on that stand. So the limiter goes where it acts, into the model's
input: the voltage in effect is the command through a limiter, RL_r(V), the law is refitted
on it, and r is the one number searched.

The search (:func:`search_rate_limit`, on the screening block):

1. Screen: r on a log grid of ``GRID_FACTORS`` times the record's 95 % quantile of the
   command's rate, scored on the training rows with the law as it is (no refit). A limit
   that cuts nothing, or whose best is the grid's top (the command is never limited), ends
   the search: most records cost these passes only.
2. Refine: a bounded search over log r within two grid steps of the screen's best, each
   trial the law refitted behind the limiter and scored on the training rows.
3. Judge on the held-out rows: the refitted law behind the limit against the registry's
   model by the search's information criterion (one parameter); and the limit's stability
   on the record's halves: each half's best limit (the refitted law held) and its scale,
   the limiter's correction fitted on each half alone (1 for a pure limiter).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Final

import numpy as np
from scipy.optimize import minimize_scalar

from es_calibration.data.align import AlignedData
from es_calibration.discovery.regression import scale_fit, stable
from es_calibration.discovery.terms import DiscoveredTerm, Discovery, with_searched_term
from es_calibration.model.composite import FitInputs
from es_calibration.search.state import (
    MIN_RELATIVE_GAIN,
    ModelState,
    Workspace,
    effective_count,
    heldout_residual,
    information_delta,
    refit_state,
)
from es_common.arrays import FloatArray, IndexArray
from es_feedforward.kernels import Backend, default_backend
from es_physics.effects.discovered import LIMITS, Carrier, rate_limited

#: Factor code of the limit (es_physics.effects.discovered.FACTORS).
LIMIT_FACTOR: Final = min(LIMITS)
#: The screen's limits: these factors of the record's 95 % quantile of |dV/dt|.
GRID_FACTORS: Final = tuple(float(f) for f in np.geomspace(0.25, 4.0, 13))
RATE_QUANTILE: Final = 0.95
#: The refinement's bracket: this many grid steps either side of the screen's best.
BRACKET_STEPS: Final = 2
#: The refinement stops within this relative step of the limit.
LIMIT_TOLERANCE: Final = 0.003
#: Each half's limit is searched within this factor of the whole record's ...
HALF_BRACKET: Final = 1.5
#: ... and must lie within this relative distance of it (a limit is a property of the
#: amplifier: measured 0.3 % apart on the halves of a stand record with one).
LIMIT_STABILITY: Final = 0.1


def rate_limited_command(aligned: AlignedData, limit: float) -> FloatArray:
    """Return the record's command (N, A) through a rate limiter of ``limit`` [V/s].

    A hole in the command counts as 0 V (as the library's signals); compiled where the
    kernels are fused (:mod:`es_calibration.model.rate_limit_loop`, the same numbers).
    """
    command = np.ascontiguousarray(np.nan_to_num(aligned.command), np.float64)
    if default_backend() is not Backend.FUSED:
        return rate_limited(command, aligned.command_period, limit)
    from es_calibration.model.rate_limit_loop import rate_limit_rows

    flat = command.reshape(command.shape[0], -1)
    out = np.empty_like(flat)
    rate_limit_rows(flat, limit * aligned.command_period, out)
    return out.reshape(command.shape)


def behind_limit(aligned: AlignedData, inputs: FitInputs, rows: IndexArray,
                 limited: FloatArray) -> FitInputs:
    """Return ``inputs`` at ``rows`` with the voltage moved by the limiter's correction.

    ``limited``: :func:`rate_limited_command` of the record. The correction RL(V) - V is
    read through the same command taps as the voltage (its fractional delay); without
    taps, at each row's command sample.
    """
    correction = np.asarray(limited) - np.nan_to_num(aligned.command)
    taps = (inputs.drive.taps if inputs.drive is not None
            else ((np.maximum(aligned.command_index(rows, 0.0), 0), 1.0),))
    moved = sum((weight * correction[at] for at, weight in taps), np.zeros(correction.shape[1]))
    return replace(inputs, voltage=inputs.voltage + np.asarray(moved).T)


def rms(residual: FloatArray) -> float:
    """Return the RMS of the finite values (NaN when none)."""
    finite = residual[np.isfinite(residual)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else float("nan")


@dataclass(frozen=True)
class LimitFit:
    """A slew-rate limit found behind the drive, and the model refitted behind it.

    Attributes:
        limit_v_per_s: the limit [V/s].
        heldout_rms_before_m: the registry model's held-out RMS (every screening row).
        heldout_rms_after_m: the refitted model's behind the limit (the same rows).
        halves_limit: the limit [V/s] best on each half of the record (time order).
        halves_scale: the limiter's correction fitted on each half (1: a pure limiter).
        stable: both halves' limits within ``LIMIT_STABILITY`` of the whole record's and
            their scales within regression.STABILITY of 1.
        accepted: it passes the information criterion and the least relative gain, and
            it is stable.

    """

    limit_v_per_s: float
    heldout_rms_before_m: float
    heldout_rms_after_m: float
    halves_limit: tuple[float, float]
    halves_scale: tuple[float, float]
    stable: bool
    accepted: bool

    def discovery(self, linear: Discovery) -> Discovery:
        """Return the step's outcome with the limit added; ``linear``'s terms stay reported.

        The limit is a used drive term, coefficient 1 (RL(V) - V adds to V).
        """
        term = DiscoveredTerm("limit", ((LIMIT_FACTOR, self.limit_v_per_s),), 1.0, 0.0,
                              self.halves_scale, self.stable, Carrier.DRIVE, used=True,
                              parameter_halves=self.halves_limit)
        return with_searched_term(term, self.heldout_rms_before_m, self.heldout_rms_after_m,
                                  linear)


def _rate_quantile(aligned: AlignedData) -> float:
    command = np.nan_to_num(aligned.command)
    rate = np.abs(np.diff(command, axis=0)) / aligned.command_period
    moving = rate[rate > 0]
    return float(np.quantile(moving, RATE_QUANTILE)) if moving.size else 0.0


def search_rate_limit(ws: Workspace, state: ModelState) -> LimitFit | None:
    """Search a slew-rate limit behind the drive of ``ws``'s record (see the module docstring).

    Returns None where no finite limit cuts the training error (the usual answer), else
    the limit with its held-out judgement (:attr:`LimitFit.accepted`).
    """
    aligned = ws.aligned
    typical = _rate_quantile(aligned)
    if typical <= 0.0:
        return None
    train_in, held_in = ws.input_pair(state.delay_s, state.play_thresholds)
    plain = rms(heldout_residual(state, train_in))

    def moved(limit: float) -> tuple[FitInputs, FitInputs]:
        limited = rate_limited_command(aligned, limit)
        return (behind_limit(aligned, train_in, ws.fit_rows, limited),
                behind_limit(aligned, held_in, ws.score_rows, limited))

    grid = typical * np.asarray(GRID_FACTORS)
    screen = [rms(heldout_residual(state, moved(limit)[0])) for limit in grid]
    if not np.isfinite(screen).any():
        return None
    best = int(np.nanargmin(screen))
    if best == grid.size - 1 or not screen[best] < (1.0 - MIN_RELATIVE_GAIN) * plain:
        return None

    def refit(limit: float) -> tuple[ModelState, FitInputs, FitInputs]:
        train, held = moved(limit)
        new = refit_state(state, train, held)
        return new, train, held

    lo = grid[max(best - BRACKET_STEPS, 0)]
    hi = grid[min(best + BRACKET_STEPS, grid.size - 1)]

    def training_rms(log_limit: float) -> float:
        new, train, _ = refit(float(np.exp(log_limit)))
        return rms(heldout_residual(new, train))

    found = minimize_scalar(
        training_rms, bounds=(float(np.log(lo)), float(np.log(hi))), method="bounded",
        options={"xatol": LIMIT_TOLERANCE})
    limit = float(np.exp(found.x))
    if limit >= grid[-1] * (1.0 - LIMIT_TOLERANCE):  # refined to the grid's top: no limit
        return None
    new, _, held = refit(limit)
    before_res = heldout_residual(state, held_in)
    after_res = heldout_residual(new, held)
    before, after = rms(before_res), rms(after_res)
    n_eff = effective_count(ws, state, held_in)
    sse = (float(np.nansum(before_res**2)), float(np.nansum(after_res**2)))
    accepted = (information_delta(sse[0], sse[1], n_eff, 1) < 0
                and after < (1.0 - MIN_RELATIVE_GAIN) * before)
    halves_limit, halves_scale = _halves(ws, new, train_in, limit)
    steady = (all(abs(h / limit - 1.0) <= LIMIT_STABILITY for h in halves_limit)
              and stable(1.0, halves_scale))
    return LimitFit(limit, before, after, halves_limit, halves_scale, steady,
                    accepted and steady)


def _halves(ws: Workspace, state: ModelState, train_in: FitInputs, limit: float
            ) -> tuple[tuple[float, float], tuple[float, float]]:
    """Return each half's best limit and its fitted scale of the limiter's correction.

    The law refitted behind ``limit`` is held; each half of the training rows (time order)
    takes the limit that fits it best and the least-squares scale of the displacement the
    limiter's correction makes at ``limit``.
    """
    aligned = ws.aligned
    late = aligned.t[ws.fit_rows] >= 0.5 * float(aligned.t[-1])
    plain = state.model.evaluate(state.fit.local, state.fit.glob, train_in,
                                 jacobian=False).prediction

    def behind(at: float) -> FloatArray:
        moved = behind_limit(aligned, train_in, ws.fit_rows, rate_limited_command(aligned, at))
        return state.model.evaluate(state.fit.local, state.fit.glob, moved,
                                    jacobian=False).prediction

    measured = np.where(train_in.valid, train_in.displacement, np.nan)
    correction = behind(limit) - plain
    limits, scales = [], []
    for half in (~late, late):
        def half_rms(x: float, half: np.ndarray = half) -> float:
            return rms((measured - behind(float(np.exp(x))))[:, half])

        found = minimize_scalar(half_rms, bounds=(float(np.log(limit / HALF_BRACKET)),
                                                  float(np.log(limit * HALF_BRACKET))),
                                method="bounded", options={"xatol": LIMIT_TOLERANCE})
        limits.append(float(np.exp(found.x)))
        scales.append(scale_fit(correction[:, half], (measured - plain)[:, half]))
    return (limits[0], limits[1]), (scales[0], scales[1])


def limit_terms(terms: list[DiscoveredTerm]) -> list[DiscoveredTerm]:
    """Return the terms of a rate limit among ``terms`` (they move the model's voltage)."""
    return [t for t in terms if any(c in LIMITS for c, _ in t.factors)]
