"""Section ``thermal``: the thermal estimators' accuracy and cost (bench_thermal.py)."""

from __future__ import annotations

from common.benchlib import Context, Record


def run(context: Context) -> None:
    """Estimation accuracy of the thermal issue's goal run (degC rms), both estimators."""
    from bench_thermal import NODE_COST_GRIDS, node_cost, thermal_accuracy

    settings, results = context.settings, context.results
    figures = thermal_accuracy()  # a seeded simulation: every repeat gives the same figures
    for name in ("thermal_rms_model", "thermal_rms_lowpass"):
        results.records.append(Record.of(name, 144, [figures[name]], "degC"))
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
