"""Section ``thermal``: the thermal estimators' accuracy and cost (bench_thermal.py)."""

from __future__ import annotations

from common.benchlib import Context, Record

#: Sensor lags [s, physical] of the stage-step runs: none, and the NTC of issue 38's stand.
STEP_LAGS = (0.0, 15.0)


def run(context: Context) -> None:
    """Estimation accuracy of the thermal goal run and of stage steps (degC rms), costs.

    Stage steps (bench_thermal.stage_steps, thesis_ac: 2 degC steps): per estimator the rms
    error over the first 30 s after each step (``thermal_step_rms_*``) and in steady state
    (``thermal_steady_rms_*``), with no sensor lag and with a 15 s one.
    """
    from bench_thermal import (
        NODE_COST_GRIDS,
        STEP_ESTIMATORS,
        node_cost,
        stage_steps,
        thermal_accuracy,
    )

    settings, results = context.settings, context.results
    figures = thermal_accuracy()  # a seeded simulation: every repeat gives the same figures
    for name in ("thermal_rms_model", "thermal_rms_lowpass"):
        results.records.append(Record.of(name, 144, [figures[name]], "degC"))
    for lag in STEP_LAGS:  # seeded simulations too: one run each
        steps = stage_steps(lag)
        for name in STEP_ESTIMATORS:
            for figure in ("step_rms", "steady_rms"):
                results.records.append(
                    Record.of(f"thermal_{figure}_{name}_lag{lag:g}", 1, [steps[f"{name}_{figure}"]],
                              "degC")
                )
        results.notes.append(
            f"thermal stage steps, sensor lag {lag:g} s: " + "; ".join(
                f"{name} max {steps[f'{name}_step_max']:.3g} degC, settled within 0.2 degC "
                f"after {steps[f'{name}_settle_s']:.0f} s" for name in STEP_ESTIMATORS
            )
        )
    for size in NODE_COST_GRIDS:
        costs = [node_cost(size, size) for _ in range(settings.repeats)]
        results.records.append(Record.of("thermal_build_time", size * size,
                                         [c["build_s"] for c in costs], "s"))
        results.records.append(Record.of("thermal_update_time", size * size,
                                         [c["update_ms_median"] for c in costs], "ms"))
    results.notes.append(
        "thermal_rms_*: bench_thermal.thermal_accuracy() defaults (dm_exposure 12 x 12, one "
        "sensor per 2 x 2 actuators, 0.01 degC noise, model parameters 20 % off); one run "
        f"(deterministic); max error model {figures['thermal_max_model']:.3g} degC, lowpass "
        f"{figures['thermal_max_lowpass']:.3g} degC; update "
        f"{figures['thermal_update_ms_model']:.2g} ms (model), "
        f"{figures['thermal_update_ms_lowpass']:.2g} ms (lowpass). thermal_build_time / "
        "thermal_update_time: bench_thermal.node_cost(), the model estimator as the thermal "
        "node builds it for the lockstep runs (dm_exposure, one sensor per actuator), one "
        "build and the median of 200 updates per repeat, in process, no DDS."
    )
