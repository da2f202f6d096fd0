"""The goal check's helpers: base steps, their settling, settled figures, estimate error."""

from __future__ import annotations

import numpy as np
import pytest

from es_bringup.goal import estimate_error, settle_time, settled_metrics, step_times
from es_bringup.metrics import AlignedRun, run_metrics
from es_sim_plant.scenario import load_scenario


def test_steps_and_their_settling_follow_the_scenario() -> None:
    ac = load_scenario("thesis_ac")
    assert step_times(ac) == pytest.approx([3.0, 6.0, 9.0, 12.0, 15.0, 18.0])
    assert step_times(load_scenario("thesis_dc_ac")) == []  # a ramp has no step
    longer = load_scenario("thesis_ac", time_scale=5 * ac.time_scale)
    assert settle_time(longer) == pytest.approx(5 * settle_time(ac))
    without_lag = ac.with_overrides(effects={"sensor_lag": False})
    assert 0 < settle_time(without_lag) < settle_time(ac)


def _run(scenario_name: str, burst_m: float) -> AlignedRun:
    """Perfect tracking except an error burst right after the base step at 3 s."""
    sc = load_scenario(scenario_name).with_overrides(control_rate=50.0, duration=6.0)
    dt = 1.0 / sc.control_rate
    t_set = np.arange(round(sc.duration / dt), dtype=np.float64) * dt
    setpoint = (50e-9 - 50e-9 * np.cos(2 * np.pi * t_set))[:, None]
    times = t_set + dt
    output = setpoint + np.where((times > 3.0) & (times < 3.2), burst_m, 0.0)[:, None]
    temperature = np.array([sc.base.at(t) for t in t_set])[:, None]
    return AlignedRun(times, setpoint, output, temperature, (1, 1))


def test_settled_figures_leave_out_the_step_transient_only() -> None:
    sc = load_scenario("thesis_ac")
    run = _run("thesis_ac", 1e-9)
    strict = run_metrics(run, 1.0, skip_s=1.0)[0]
    settled = settled_metrics(run, 1.0, sc, skip_s=1.0)
    assert strict.variation_m > 1e-10  # the burst, averaged with the other periods at 42 degC
    assert settled is not None and settled.variation_m < 1e-15
    assert settled_metrics(run, 1.0, load_scenario("thesis_dc_ac"), skip_s=1.0) is None


def test_estimate_error_is_measured_against_the_true_actuator_temperature() -> None:
    sc = load_scenario("thesis_ac").with_overrides(control_rate=50.0, duration=6.0)
    run = _run("thesis_ac", 0.0)
    held = AlignedRun(
        run.times, run.setpoint, run.output, np.full_like(run.temperature, 40.0), run.grid_shape
    )
    # an estimate stuck at 40 degC misses the 40 -> 42 degC step by its full height
    assert estimate_error(held, sc) == pytest.approx(2.0, abs=0.01)
