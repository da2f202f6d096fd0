"""Pairs of effects in the search, on independent test-stand data (testing/standgen).

Each test is a cause found in a pair case of the identification sweep, shortened: the data
come from standgen's API (not our plant), the search steps are run on them directly.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from standgen import StandConfig, simulate
from standgen.effects import Drift, Effects, FrequencyDispersion, Hysteresis, SelfHeating
from standgen.stand import AC_SPLIT_TAU_S
from standgen.sweep import build_cases

from es_calibration.data.align import align
from es_calibration.model.composite import CompositeModel
from es_calibration.pipeline import _search
from es_calibration.search.scans import candidate_states
from es_calibration.search.selection import (
    _backward_round,
    search_effects,
    settle_operators,
)
from es_calibration.search.state import (
    Workspace,
    base_state,
    choose_stamp_convention,
    effect_parameters,
    extend_local,
    fit_state,
)

from .stand_data import measured


def _workspace(config: StandConfig) -> tuple[Workspace, float]:
    """Return the workspace of a stand recording (whole grid) and the stand's true noise [m]."""
    aligned = choose_stamp_convention(align(measured(simulate(config))))
    actuators = np.arange(aligned.n_actuators, dtype=np.intp)
    return Workspace(aligned, actuators, (config.rows, config.cols)), config.noise_rms_m


def test_drift_fits_on_top_of_a_coupling_from_every_start() -> None:
    # sweep case drift+coupling: the coupled law's Jacobian is approximate and the drift
    # strongly nonlinear in its time constant; the fit stopped after three rejected steps
    # where it started (worse than without the drift) and the drift was never accepted
    case = next(c for c in build_cases() if c.name == "drift+coupling")
    # the sweep's case (with its temperature gap) on a 3 x 3 grid at 250 Hz, grid sensors
    config = replace(case.config, rows=3, cols=3, rate_hz=250.0, temperature_kind="grid")
    truth = config.effects.drift
    assert truth is not None
    ws, noise = _workspace(config)
    duration = float(ws.aligned.t[-1])
    base = base_state(ws)
    coupled = min(candidate_states(ws, base, "coupling", duration), key=lambda s: s.fit.total_cost)
    assert coupled.heldout_rms > 1.5 * noise  # the drift is left to explain
    starts = candidate_states(ws, coupled, "drift", duration)
    assert len(starts) >= 2
    for state in starts:  # no start ends worse than the model without the drift
        assert state.fit.total_cost <= coupled.fit.total_cost
    best = min(starts, key=lambda s: s.fit.total_cost)
    assert best.heldout_rms < 1.2 * noise
    found = effect_parameters(best, "drift", ws.aligned)
    assert abs(found["fraction"] - truth.fraction) < 0.2 * truth.fraction
    assert abs(found["tau_s"] - truth.tau_s) < 0.2 * truth.tau_s


def test_the_self_heating_window_is_fitted_to_the_stands_split_of_the_drive() -> None:
    # sweep case hysteresis+self_heating: the stand measures the loss against the drive's
    # 1.6 s low-pass (its own split of level and swing), the calibration measured it against
    # a fixed 1 s running mean, and 1.22x the noise was left with the right effects
    config = StandConfig(
        rows=1,
        cols=1,
        rate_hz=1000.0,
        duration_s=24.0,
        temperature_kind="grid",
        noise_m=0.4e-9,
        effects=Effects(self_heating=SelfHeating(gain=2.5e-5, tau_s=0.76)),
        seed=59,
    )
    ws, noise = _workspace(config)
    base = base_state(ws)
    heated = min(
        candidate_states(ws, base, "self_heating", float(ws.aligned.t[-1])),
        key=lambda s: s.fit.total_cost,
    )
    found = effect_parameters(heated, "self_heating", ws.aligned)
    assert abs(found["mean_window_s"] - AC_SPLIT_TAU_S) < 0.15 * AC_SPLIT_TAU_S
    assert abs(found["tau_s"] - 0.76) < 0.15 * 0.76
    assert heated.heldout_rms < 1.1 * noise


def test_an_unphysical_extra_play_operator_is_dropped_not_the_hysteresis() -> None:
    # sweep case hysteresis+drift: three play operators were fitted, then the joint refit
    # with the drift took the third weight below zero; the backward check called the whole
    # hysteresis unphysical and dropped it (2.2x the noise left)
    config = StandConfig(
        rows=1,
        cols=1,
        rate_hz=250.0,
        duration_s=24.0,
        temperature_kind="grid",
        effects=Effects(
            hysteresis=Hysteresis((25.0, 55.0), (0.03, 0.045)), drift=Drift(0.05, 8.0, 1.2)
        ),
        seed=5,
    )
    ws, noise = _workspace(config)
    base = base_state(ws)
    model = CompositeModel(("hysteresis", "drift"), operators=3)
    thresholds = (25.0, 55.0, 120.0)
    start = {
        "hysteresis.weight": 0.03,
        "hysteresis.weight_2": 0.045,
        "hysteresis.weight_3": -0.002,
        "drift.fraction": 0.05,
        "drift.log_tau_s": float(np.log(8.0)),
        "drift.log_nu": float(np.log(1.2)),
    }
    glob = np.array([start.get(n, 0.0) for n in model.global_names])
    train, held = ws.input_pair(0.0, thresholds)
    unsettled = fit_state(  # the state as the joint refit left it (no iteration)
        model,
        train,
        held,
        extend_local(base, model),
        glob,
        delay_s=0.0,
        thresholds=thresholds,
        max_iter=0,
    )
    record, _ = _backward_round(ws, unsettled)
    assert record.removed == "hysteresis"  # what the backward check did before

    settled = settle_operators(ws, unsettled)
    assert settled.model.operators == 2 and settled.thresholds == (25.0, 55.0)
    params = effect_parameters(settled, "hysteresis", ws.aligned)
    assert 0.0 < params["weight"] < 1.0 and 0.0 < params["weight_2"] < 1.0
    assert settled.heldout_rms < 1.2 * noise
    record, reduced = _backward_round(ws, settled)
    assert reduced is None and record.removed is None  # both effects are needed


def test_a_rival_with_a_whiter_but_larger_residual_does_not_take_the_place() -> None:
    # sweep case sensor_lag+coupling: drift's own criterion beat sensor_lag's in the first
    # round (its residual whiter, so counted as more independent samples) though sensor_lag
    # left the smaller held-out residual; drift+coupling was accepted (2.0x the noise left)
    case = next(c for c in build_cases() if c.name == "sensor_lag+coupling")
    config = replace(case.config, rate_hz=1000.0, temperature_kind="grid")
    ws, noise = _workspace(config)
    base = base_state(ws)
    candidates = ("sensor_lag", "drift", "coupling")
    final, _, rounds = search_effects(ws, base, candidates)
    first = {s.name: s for s in rounds[0].scores}
    assert first["sensor_lag"].reason == first["coupling"].reason == "passes"
    # drift's fraction moves once each actuator may carry a constant offset (offsets.py)
    assert first["drift"].reason.startswith(("passes", "stand-in: "))
    # the sweep's situation had drift's own criterion lowest, not its held-out RMS; the
    # samples at the command's unresolvable edges (edges.py) made that, and are left out now
    assert first["sensor_lag"].rms_after_m < first["drift"].rms_after_m
    # with per-actuator edge masks coupling may come first; drift must never take a place
    assert "drift" not in {r.added for r in rounds}
    assert set(final.model.effects) == {"sensor_lag", "coupling"}
    assert final.heldout_rms < 1.2 * noise
    found = effect_parameters(final, "sensor_lag", ws.aligned)
    truth = config.effects.sensor_lag
    assert truth is not None
    assert abs(found["tau_s"] - truth.tau_s) < 0.2 * truth.tau_s


def test_a_sub_period_delay_that_only_undoes_a_wrong_stamp_convention_is_not_kept() -> None:
    # sweep cases frequency_dispersion+drift, frequency_dispersion+coupling, hysteresis-2:
    # command and displacement share stamps; the plain law took the command as not yet in
    # effect at its own stamp (wrong: the stand applies it at once), then a "delay" of 0.05
    # of a period (a shift of -0.95) undid that, and was reported as an effect
    config = StandConfig(
        rows=1,
        cols=1,
        rate_hz=2000.0,
        duration_s=8.0,
        temperature_kind="grid",
        effects=Effects(frequency_dispersion=FrequencyDispersion(0.12, 3.3)),
        seed=1,
    )
    ws, noise = _workspace(config)
    assert ws.aligned.has_same_stamps and not ws.aligned.include_same_stamp  # the wrong guess
    aligned, _, _, final, _, _ = _search(ws.aligned, ws.grid, ("frequency_dispersion", "delay"))
    assert aligned.include_same_stamp
    assert final.model.effects == ("frequency_dispersion",)
    assert final.heldout_rms < 1.2 * noise
    found = effect_parameters(final, "frequency_dispersion", aligned)
    assert abs(found["fraction"] - 0.12) < 0.02
