"""``calibration.json`` and the feedforward parameters YAML written from a :class:`Calibration`.

calibration.json (schema version 3; SI units, degC; "1-sigma" uncertainties inflated for the
residual's autocorrelation)::

    {
      "schema_version": 3,
      "grid": {"rows": R, "cols": C},
      "data": {"start_time_s", "duration_s", "sample_rate_hz", "command_period_s",
               "temperature_topic", "samples", "training_samples", "heldout_samples",
               "blocks", "command_in_effect_at_same_stamp", "dropped": {reason: count},
               "repeated_stamps": how repeated stamps were resolved, "" if none,
               "gaps": [{"topic", "start_s" (bag time of the last message before the gap),
                         "duration_s", "missing_samples", "excluded_samples"}],
               "command_edges": {"edges" (intervals that are an edge for some actuator),
                                 "pairs" (edge x actuator), "excluded_pairs" ((sample,
                                 actuator) pairs the actuators' own edges take out),
                                 "excluded_fraction" (of the block's pairs),
                                 "example_times_s" (bag times of the first edges),
                                 "excluded_before_s", "excluded_after_s" (the window at
                                 the known delay), "delay_s",
                                 "per_actuator": {"edges", "excluded_samples"} (lists over
                                 the screening block's actuators)} or null,
               "grid_command_edges": the same over the whole grid, each actuator's own
                                     edges (lists over R*C), when the grid is larger than
                                     the screening block; else null,
               "temperature_span": {"start_s", "end_s" (bag times of the first and last
                                    temperature messages), "excluded_before",
                                    "excluded_after" (samples outside them)} or null},
      "law": {"L", "Tm" (fixed), "m1", "m2", "m3", "k1", "k2", "k3": row-major lists of R*C,
              "uncertainty": {same names: lists of R*C 1-sigma values}},
      "effects": [{"name": canonical name, "parameters": {...}, "uncertainties": {...},
                   "rms_before_m", "rms_after_m",
                   "share": part of the mean-square error all effects removed (sum 1),
                   "per_actuator": {parameter: row-major list of R*C values} for those
                   fitted per actuator (their "parameters" entry is the grid's median),
                   "per_actuator_uncertainties": {same names: 1-sigma lists}}],
      "candidates": [[{"name", "step", "rms_before_m", "rms_after_m", "delta_bic",
                       "accepted", "reason", "parameters"}], ...],  # every round
      # step "forward": adding the candidate; "backward": removing an accepted effect
      # (rms_before_m without it, rms_after_m with it, accepted = it stays);
      # "per_actuator": an accepted effect's parameter as one value per actuator
      # (rms_before_m with one grid value, rms_after_m with one per actuator)
      # "halves": the final model refitted on the first / second half of the record
      # (rms_before_m / rms_after_m: each half's held-out RMS; accepted = the effect's
      # parameters agree between the halves, else reason "stand-in: ..." and the effect
      # is written with "enabled": false)
      # "stand_in": with discovered terms added, each accepted effect taken out and the
      # discovery run again without it (rms_before_m: without it and its own terms,
      # rms_after_m: with it and the terms; accepted = it stays, else it was a stand-in
      # and is gone from the model)
      "heldout_rms_before_m", "heldout_rms_after_m",         # whole grid, held-out rows
      "heldout_max_before_m", "heldout_max_after_m",         # analysed actuators, full rate
      "noise_floor_m": white measurement noise estimated from the final residual,
      "unexplained": ["remaining structure, in words", ...],
      "timings_s": {step: seconds},
      "search_span": what of the record the effect search saw ("whole record", or its
                     windows on a record longer than the search budget),
      "discovered": {"searched", "terms": [{"name", "expression", "coefficient", "unit",
                     "share", "stable", "halves", "mechanism", "side", "acts_on"
                     ("displacement", "drive", "temperature" or "measurement"),
                     "compensable", "used" (the model is refitted with it), "written"
                     (in the parameters file: used, and not of the measurement),
                     "parameter_halves" (a slew-rate limit's [V/s] on each half, else
                     null)}],
                     "added", "heldout_rms_before_m", "heldout_rms_after_m",
                     "heldout_rms_all_terms_m" (screening block, held-out rows: registry
                     model, + the terms written, + every selected term), "note",
                     "library_size", "seconds"},
      "health": {"findings": [{"kind", "subject", "index", "row", "col", "start_s",
                               "end_s", "value", "unit", "sentence", "action"}]
                              (health/findings.py),
                 "clock_rate_ppm": the displacement logger's clock against the command's
                                   (data/timing.py; null: not estimated),
                 "kept_fraction": share of the screening block's (displacement sample x
                                  actuator) pairs kept for the fit,
                 "grid_kept_fraction": the whole grid's, at least (a pair both NaN and at
                                       an edge counts twice), or null when the grid is
                                       the block}
      "verdict": {"level": "trusted" | "provisional" | "unusable", "reasons": [...]},
      "thermal_params": {"file" (the thermal node's parameters file beside this one),
                         "time_scale" (the recording's, given to the tool), "temperature_topic",
                         "sensor_lag_tau", "sensor_offsets", "sensor_offsets_sd" (as written
                         in the file: physical s / degC, one value or one per sensor),
                         "sensor_lag_tau_sd" (the lag's 1-sigma, physical s)}
                        (output/thermal_file.py; absent when the tool wrote no such file)
    }

Effects carry ``"enabled"``: false for one that did not hold on the record's halves (its
compensation is left out of the YAML); a refused stand-in's candidate reason starts with
``"stand-in: "``.

Effect parameters use the names the effects declare (:mod:`es_physics.effects`); the YAML
carries them as each effect's ``compensation.*`` parameters (and law.m3/k3 for the ``LAW``
effect's per-actuator coefficients).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Final

import numpy as np

from es_calibration.pipeline import Calibration, fitted_law
from es_feedforward.compensation import RANGES, CompensationParams
from es_feedforward.feedforward import FeedforwardConfig
from es_feedforward.param_file import write_params_file
from es_physics.effects import get
from es_physics.effects.discovered import values_from_terms
from es_physics.params import ActuatorParams

SCHEMA_VERSION: Final = 3


def fitted_params(cal: Calibration) -> ActuatorParams:
    """Return the fitted law as per-actuator maps (R, C)."""
    return fitted_law(cal.final, cal.aligned.grid)


def law_uncertainty(cal: Calibration) -> dict[str, list[float]]:
    """Return 1-sigma uncertainties of the fitted law coefficients (row-major lists)."""
    cov = cal.final.fit.cov_local
    sig = np.sqrt(np.maximum(np.einsum("app->ap", cov), 0.0))
    model = cal.final.model
    return {
        n: sig[:, i].tolist()
        for i, n in enumerate(model.local_names)
        if n not in model.per_actuator
    }


def compensation(cal: Calibration) -> tuple[CompensationParams, list[str]]:
    """Return the compensation of the accepted effects and notes on values clipped to range.

    An effect not confirmed (``enabled`` false) is left switched off.
    """
    values: dict[str, float] = {}
    for effect in (e for e in cal.effects if e.enabled):
        values.update(
            get(effect.name).compensation_values(effect.parameters, cal.aligned.start_time)
        )
    if cal.discovery is not None:
        values.update(values_from_terms([t.term for t in cal.discovery.written]))
    notes = []
    for name, value in list(values.items()):
        low, high = RANGES[name]
        if not low <= value <= high:
            values[name] = float(np.clip(value, low, high))
            notes.append(f"compensation.{name} = {value:.4g} clipped to [{low}, {high}]")
    return CompensationParams().replaced(values), notes


def write_parameters_yaml(cal: Calibration, path: Path) -> list[str]:
    """Write the feedforward parameters YAML; return notes on clipped values."""
    comp, notes = compensation(cal)
    config = FeedforwardConfig(shape=cal.aligned.grid, params=fitted_params(cal), compensation=comp)
    write_params_file(
        path, config, verdict=(cal.verdict.level, list(cal.verdict.reasons))
    )
    return notes


def _float(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _float(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_float(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def calibration_document(
    cal: Calibration, thermal: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Return the calibration.json document (see the module docstring).

    ``thermal``: the ``thermal_params`` section (the thermal node's file and its values).
    """
    a = cal.aligned
    params = fitted_params(cal)
    law: dict[str, Any] = {
        name: np.broadcast_to(np.asarray(getattr(params, name)), a.grid).ravel().tolist()
        for name in ("L", "Tm", "m1", "m2", "m3", "k1", "k2", "k3")
    }
    law["uncertainty"] = law_uncertainty(cal)
    doc = {
        "schema_version": SCHEMA_VERSION,
        "grid": {"rows": a.grid[0], "cols": a.grid[1]},
        "data": {
            "start_time_s": a.start_time,
            "duration_s": float(a.t[-1]),
            "sample_rate_hz": a.sample_rate,
            "command_period_s": a.command_period,
            "temperature_topic": a.temperature_source,
            "samples": int(a.t.size),
            "training_samples": int(a.train.sum()),
            "heldout_samples": int((~a.train).sum()),
            "blocks": int(a.block_edges.size - 1),
            "command_in_effect_at_same_stamp": a.include_same_stamp,
            "dropped": a.dropped,
            "repeated_stamps": a.repeated_stamps,
            "gaps": [g.as_dict() for g in a.gaps],
            "command_edges": a.command_edges.as_dict() if a.command_edges else None,
            "grid_command_edges": cal.grid_edges.as_dict() if cal.grid_edges else None,
            "temperature_span": a.temperature_span.as_dict() if a.temperature_span else None,
        },
        "law": law,
        "effects": [
            {
                "name": e.name,
                "parameters": e.parameters,
                "uncertainties": e.uncertainties,
                "rms_before_m": e.rms_before_m,
                "rms_after_m": e.rms_after_m,
                "share": e.share,
                "per_actuator": e.per_actuator,
                "per_actuator_uncertainties": e.per_actuator_uncertainties,
                "enabled": e.enabled,
            }
            for e in cal.effects
        ],
        "candidates": [
            [
                {
                    "name": s.name,
                    "step": r.step,
                    "rms_before_m": s.rms_before_m,
                    "rms_after_m": s.rms_after_m,
                    "delta_bic": s.delta_ic,
                    "accepted": s.accepted,
                    "reason": s.reason,
                    "parameters": s.parameters,
                }
                for s in r.scores
            ]
            for r in cal.rounds
        ],
        "heldout_rms_before_m": cal.base.heldout_rms,
        "heldout_rms_after_m": cal.final.heldout_rms,
        "heldout_max_before_m": cal.before.max_abs,
        "heldout_max_after_m": cal.after.max_abs,
        "noise_floor_m": cal.noise_floor_m,
        "unexplained": cal.unexplained,
        "timings_s": cal.timings_s,
        "search_span": cal.search_span or "whole record",
        "discovered": cal.discovery.as_dict() if cal.discovery is not None else {
            "searched": False, "terms": [], "added": False,
            "heldout_rms_before_m": cal.final.heldout_rms,
            "heldout_rms_after_m": cal.final.heldout_rms,
        },
        "health": {
            "findings": [f.as_dict() for f in cal.findings],
            "clock_rate_ppm": cal.clock_rate_ppm,
            "kept_fraction": cal.kept_fraction,
            "grid_kept_fraction": cal.grid_kept_fraction,
        },
        "verdict": cal.verdict.as_dict(),
    }
    if thermal is not None:
        doc["thermal_params"] = thermal
    return dict(_float(doc))


def write_calibration_json(
    cal: Calibration, path: Path, thermal: dict[str, Any] | None = None
) -> None:
    """Write calibration.json (with its ``thermal_params`` section when given)."""
    text = json.dumps(calibration_document(cal, thermal), indent=1, allow_nan=True)
    path.write_text(text + "\n", encoding="utf-8")
