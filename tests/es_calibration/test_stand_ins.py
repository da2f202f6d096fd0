"""The stand-in check with the discovered terms (es_calibration.discovery.standins).

Real models on an independent stand record (a drift effect fitted on top of the basic law),
the discovery's answers given: the check must keep the effect when the model without it,
with its own terms, explains the held-out rows worse, remove it (and take the other answer)
when that model explains them better with no more unknowns, and compare nothing when the
discovery added no term.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from standgen import StandConfig, simulate

from es_calibration.data.align import align
from es_calibration.discovery.standins import STEP, Added, drop_stand_ins
from es_calibration.discovery.terms import DiscoveredTerm, Discovery
from es_calibration.search.selection import subset_state
from es_calibration.search.state import ModelState, Workspace, base_state, choose_stamp_convention

from .stand_data import measured

CONFIG = StandConfig(rows=2, cols=2, rate_hz=500.0, duration_s=20.0, noise_m=0.5e-9, seed=5,
                     temperature_kind="grid")
TERM = DiscoveredTerm("discovered_1", ((11, 0.5),), 1e-13, 0.5, (1e-13, 1e-13), True,
                      used=True)


@cache
def _models() -> tuple[Workspace, ModelState, list[Added]]:
    aligned = choose_stamp_convention(align(measured(simulate(CONFIG))))
    ws = Workspace(aligned, np.arange(aligned.n_actuators), aligned.grid)
    base = base_state(ws)
    with_drift = subset_state(ws, base, ("drift",))
    return ws, base, [("drift", base, with_drift)]


def _answer(after_m: float) -> Discovery:
    return Discovery(True, [TERM], True, 2e-9, after_m, heldout_rms_all_terms_m=after_m)


def test_an_effect_the_terms_cannot_replace_stays() -> None:
    ws, base, added = _models()
    kept, discovery, record = drop_stand_ins(ws, base, added, _answer(1.0e-9),
                                             lambda state: _answer(1.5e-9))
    assert record is not None and record.step == STEP and record.removed is None
    assert kept == added and discovery.heldout_rms_after_m == 1.0e-9
    assert record.scores[0].accepted and record.scores[0].delta_ic < 0


def test_a_stand_in_goes_and_the_model_without_it_takes_its_terms() -> None:
    ws, base, added = _models()
    seen: list[tuple[str, ...]] = []

    def rediscover(state: ModelState) -> Discovery:
        seen.append(state.model.effects)
        return _answer(0.9e-9)

    kept, discovery, record = drop_stand_ins(ws, base, added, _answer(1.0e-9), rediscover)
    assert seen == [()]  # the discovery ran again on the model without the drift
    assert record is not None and record.removed == "drift"
    assert kept == [] and discovery.heldout_rms_after_m == 0.9e-9
    assert "stand-in" in record.scores[0].reason


def test_nothing_is_compared_without_added_terms() -> None:
    ws, base, added = _models()
    nothing = Discovery(True, [], False, 2e-9, 2e-9)
    kept, discovery, record = drop_stand_ins(ws, base, added, nothing,
                                             lambda state: _answer(0.1e-9))
    assert record is None and kept == added and discovery is nothing


def test_after_a_removal_the_other_effects_are_judged_again() -> None:
    ws, base, added = _models()
    with_drift = added[0][2]
    both = subset_state(ws, with_drift, ("drift", "coupling"))
    two: list[Added] = [*added, ("coupling", with_drift, both)]
    answers = iter([0.9e-9, 0.8e-9])
    seen: list[tuple[str, ...]] = []

    def rediscover(state: ModelState) -> Discovery:
        seen.append(state.model.effects)
        return _answer(next(answers))

    kept, discovery, record = drop_stand_ins(ws, base, two, _answer(1.0e-9), rediscover)
    # the last effect first; then the drift, judged against the answer without the coupling
    assert seen == [("drift",), ()]
    assert record is not None and record.removed == "coupling, drift"
    assert kept == [] and discovery.heldout_rms_after_m == 0.8e-9
    assert [s.name for s in record.scores] == ["coupling", "drift"]
