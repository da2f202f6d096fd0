"""The discovery's logarithmic creep: one term, its coefficient found with the law refitted.

A piezo's strain keeps moving after each change of its drive, by about the same amount per
decade of time (z (1 + gamma log10(t / t0))); a Prony series of first-order lags, one per
decade, each of weight gamma, is the usual way to write it (es_physics' factor 20, the
library's ``creep(z)``: the low-passes of the modelled displacement minus it). Scored as the
library's terms are (projected on the law's linearised unknowns), the creep comes out no
better than any smooth function of the displacement: on a stand record with creep of 1.3 %
per decade a fringe term took it (0.52 nm left of 1.2 nm, noise 0.30 nm), while the creep
term with the law refitted on the data without it leaves 0.30 nm. The creep changes the
law's apparent gain by gamma per decade, so only the exact refit tells it. Hence a search of
its own (:func:`search_creep`, on the screening block, as the slew-rate limit's):

1. Screen: the shortest time constant on a log grid of ``SHORTEST_PERIODS`` command periods,
   gamma fitted by least squares on the training rows with the law as it is. A creep that
   cuts nothing, or gamma not positive (the strain would run back), ends the search.
2. Refine: a simplex search over the logs of the shortest time constant and gamma, each
   trial the law refitted on the data without the creep, scored on the training rows.
3. Judge on the held-out rows by the search's information criterion (two parameters) and
   the least relative gain; and on the record's halves: gamma fitted on each half (the
   refitted law held) within regression.STABILITY of the whole record's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Final

import numpy as np
from scipy.optimize import minimize

from es_calibration.discovery.exact import library_for, moved_inputs
from es_calibration.discovery.library import Rows
from es_calibration.discovery.limit import rms
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
from es_common.arrays import FloatArray
from es_physics.effects.discovered import CREEP, Carrier

#: The screen's shortest time constants, in command periods.
SHORTEST_PERIODS: Final = tuple(float(p) for p in np.geomspace(1.0, 100.0, 9))
#: The refinement: a simplex over (log shortest, log gamma) from the screen's best, its first
#: steps (a grid step of the screen, half of gamma), at most this many refits, to this step.
REFINE_STEPS: Final = (float(np.log(100.0) / 8), float(np.log(1.5)))
REFINE_EVALUATIONS: Final = 40
REFINE_TOLERANCE: Final = 0.01
#: Unknowns the creep adds: gamma and the shortest time constant.
UNKNOWNS: Final = 2


@dataclass(frozen=True)
class CreepFit:
    """A logarithmic creep found in the displacement, and the model refitted without it.

    Attributes:
        shortest_s: the shortest of its time constants [s] (the others one decade apart).
        gamma: its weight per decade (the term's coefficient).
        heldout_rms_before_m: the registry model's held-out RMS (every screening row).
        heldout_rms_after_m: the model refitted with the creep's (the same rows).
        halves: gamma fitted on each half of the record (time order).
        stable: both halves' gamma within regression.STABILITY of the whole record's.
        accepted: it passes the information criterion and the least relative gain, and it
            is stable.

    """

    shortest_s: float
    gamma: float
    heldout_rms_before_m: float
    heldout_rms_after_m: float
    halves: tuple[float, float]
    stable: bool
    accepted: bool

    def discovery(self, linear: Discovery) -> Discovery:
        """Return the step's outcome with the creep added; ``linear``'s terms stay reported."""
        term = replace(_term(self.shortest_s, self.gamma), halves=self.halves, stable=self.stable)
        return with_searched_term(term, self.heldout_rms_before_m, self.heldout_rms_after_m,
                                  linear)


def _term(shortest: float, gamma: float) -> DiscoveredTerm:
    """Return a used creep term of ``gamma`` per decade from ``shortest`` [s]."""
    return DiscoveredTerm("creep", ((CREEP, shortest),), gamma, 0.0, (gamma, gamma), True,
                          Carrier.DISPLACEMENT, used=True)


def search_creep(ws: Workspace, state: ModelState) -> CreepFit | None:
    """Search a logarithmic creep in ``ws``'s record (see the module docstring).

    Returns None where no creep cuts the training error (the usual answer), else the creep
    with its held-out judgement (:attr:`CreepFit.accepted`).
    """
    train_in, held_in = ws.input_pair(state.delay_s, state.play_thresholds)
    residual = heldout_residual(state, train_in)
    plain = rms(residual)
    library = library_for(ws, state, None, None)
    zeros = np.zeros_like(residual)

    def column(shortest: float) -> FloatArray:
        """Return the creep factor (A, n) at the training rows."""
        at = Rows(ws.fit_rows, zeros, zeros, zeros, zeros)
        return library.signals(at, [(CREEP, shortest)])[(CREEP, shortest)]

    screen = []
    for periods in SHORTEST_PERIODS:
        shortest = periods * ws.aligned.command_period
        c = column(shortest)
        gamma = scale_fit(c, residual)
        screen.append((rms(residual - gamma * c), shortest, gamma))
    best, shortest, gamma = min(screen)
    if not (gamma > 0.0 and best < (1.0 - MIN_RELATIVE_GAIN) * plain):
        return None

    def training_rms(x: FloatArray) -> float:
        """Return the training RMS with the law refitted, creep at (log shortest, log gamma)."""
        train, held = moved_inputs(ws, state, [_term(*np.exp(x))], None, library)
        new = refit_state(state, train, held)
        return rms(heldout_residual(new, train))

    start = np.log([shortest, gamma])
    simplex = np.vstack([start, start + np.diag(REFINE_STEPS)])
    found = minimize(training_rms, start, method="Nelder-Mead", options={
        "maxfev": REFINE_EVALUATIONS, "initial_simplex": simplex, "xatol": REFINE_TOLERANCE,
        "fatol": 0.0})
    if not np.isfinite(found.fun):
        return None
    shortest, gamma = (float(v) for v in np.exp(found.x))
    train, held = moved_inputs(ws, state, [_term(shortest, gamma)], None, library)
    new = refit_state(state, train, held)
    before_res = heldout_residual(state, held_in)
    after_res = heldout_residual(new, held)
    before, after = rms(before_res), rms(after_res)
    n_eff = effective_count(ws, state, held_in)
    sse = (float(np.nansum(before_res**2)), float(np.nansum(after_res**2)))
    accepted = (information_delta(sse[0], sse[1], n_eff, UNKNOWNS) < 0
                and after < (1.0 - MIN_RELATIVE_GAIN) * before)
    halves = _halves(ws, new, train_in, column(shortest))
    steady = stable(gamma, halves)
    return CreepFit(shortest, gamma, before, after, halves, steady, accepted and steady)


def _halves(ws: Workspace, state: ModelState, train_in: FitInputs, column: FloatArray
            ) -> tuple[float, float]:
    """Return gamma fitted on each half of the training rows, ``state``'s law held."""
    late = ws.aligned.t[ws.fit_rows] >= 0.5 * float(ws.aligned.t[-1])
    residual = heldout_residual(state, train_in)
    first, second = (scale_fit(column[:, half], residual[:, half])
                     for half in (~late, late))
    return first, second
