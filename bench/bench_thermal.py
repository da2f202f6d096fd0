"""Accuracy of the temperature estimators against the simulator's true actuator temperatures.

Usage (from the repository root, after ./scripts/bootstrap)::

    .venv/bin/python bench/bench_thermal.py [--scenario dm_exposure] [--pitch 2]
        [--noise 0.01] [--error 0.2] [--pattern mixed|high|low|exact] [--duration S]
        [--time-scale X] [--sensor-rate HZ] [--sensor-lag]
    .venv/bin/python bench/bench_thermal.py --cost 32x32/2     # build and update time
    .venv/bin/python bench/bench_thermal.py --node-cost 64x64  # ... as the node builds it
    .venv/bin/python bench/bench_thermal.py --steps [--lag 15]  # stage steps (thesis_ac)

The issue-5 goal run (the defaults): ``dm_exposure`` with 0.01 degC sensor noise, one sensor
per 2 x 2 actuators (at the block centres, reading the bilinear mean of the four), no sensor
offsets, and the ``model`` estimator's thermal parameters 20 % off the simulator's
(``mixed``: C_f, G_fa, G_ff +20 %; C_a, G_ab, G_aa -20 %, so gains and time constants are both
wrong; ``high``/``low``: all +-20 %). The ``lowpass`` estimator is the thesis's: 2nd-order
Butterworth at 0.1 Hz physical, i.e. 0.1 Hz / time_scale in a shortened scenario, so that
both see the same dynamics. The first 10 % of the run (start-up) is not scored.

:func:`thermal_accuracy` returns the figures (``thermal_rms_model``, ``thermal_rms_lowpass``
and more) for the benchmark suite, :func:`stage_steps` the estimate's error on the stage
steps of ``thesis_ac`` (2 degC steps, optionally behind a lagging sensor) for the low-pass,
the model estimator as before and with its stage-step gain, :func:`update_cost` the model
estimator's cost,
:func:`node_cost` that of the estimator the thermal node builds for the lockstep benchmark;
``main`` prints them as JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, fields, replace

import numpy as np

from es_sim_plant.plant import Plant, simulate
from es_sim_plant.scenario import Scenario, load_scenario
from es_thermal.estimator import EstimatorConfig, TemperatureEstimator
from es_thermal.evaluation import replay, score
from es_thermal.interpolation import actuator_positions, block_centre_positions
from es_thermal.kalman import KalmanTuning
from es_thermal.lowpass import DEFAULT_CUTOFF_HZ
from es_thermal.network import NetworkParams

#: Parameters scaled up (the others down) by the ``mixed`` error pattern.
_MIXED_UP = ("face_capacitance", "face_to_actuator", "face_lateral")


def misjudged(params: NetworkParams, error: float, pattern: str) -> NetworkParams:
    """Return ``params`` as an estimator that gets them ``error`` (relative) wrong believes them."""
    if pattern == "exact":
        return params
    if pattern in ("high", "low"):
        return params.scaled(1.0 + error if pattern == "high" else 1.0 - error)
    if pattern != "mixed":
        raise ValueError(f"unknown error pattern {pattern!r}")
    return replace(
        params,
        **{
            f.name: getattr(params, f.name) * (1.0 + error if f.name in _MIXED_UP else 1.0 - error)
            for f in fields(params)
        },
    )


def goal_scenario(
    name: str,
    pitch: int,
    noise: float,
    *,
    duration: float | None = None,
    time_scale: float | None = None,
    sensor_rate: float | None = None,
    effects: dict[str, bool] | None = None,
    keep_offsets: bool = False,
) -> Scenario:
    """Return ``name`` with the goal's sensors.

    One sensor per ``pitch`` x ``pitch`` block, ``noise`` rms, the scenario's quantisation,
    no offsets unless ``keep_offsets`` (the scenario's fixed per-sensor offsets: no
    estimator can tell them from temperature without a calibration).
    """
    sc = load_scenario(name, time_scale=time_scale).with_overrides(
        duration=duration, sensor_rate=sensor_rate, effects=effects
    )
    positions = (
        None
        if pitch == 1
        else tuple((float(r), float(c)) for r, c in block_centre_positions(sc.rows, sc.cols, pitch))
    )
    sensors = replace(sc.sensors, positions=positions, noise_sd=noise)
    if not keep_offsets:
        sensors = replace(sensors, offset_sd=0.0, offsets=None)
    return replace(sc, sensors=sensors)


def thermal_accuracy(
    scenario: str = "dm_exposure",
    *,
    pitch: int = 2,
    noise: float = 0.01,
    error: float = 0.2,
    pattern: str = "mixed",
    duration: float | None = None,
    time_scale: float | None = None,
    sensor_rate: float | None = None,
    effects: dict[str, bool] | None = None,
    keep_offsets: bool = False,
) -> dict[str, float]:
    """Simulate ``scenario`` and score both estimators on it; return the figures [degC, s].

    ``duration`` (sim s), ``time_scale`` and ``sensor_rate`` [Hz] override the scenario's
    (``None`` keeps them), ``effects`` switches simulator effects (e.g. ``sensor_lag``,
    compensated by the model estimator with the simulator's tau); a shortened scenario
    needs a sensor rate above twice the scaled low-pass cut-off.

    Keys: ``thermal_rms_model``, ``thermal_rms_lowpass``, ``thermal_max_model``,
    ``thermal_max_lowpass``, ``thermal_lag_model``, ``thermal_lag_lowpass``,
    ``thermal_update_ms_model``, ``thermal_update_ms_lowpass`` (mean wall time per update),
    ``temperature_span`` (range of the true actuator temperatures).
    """
    sc = goal_scenario(
        scenario,
        pitch,
        noise,
        duration=duration,
        time_scale=time_scale,
        sensor_rate=sensor_rate,
        effects=effects,
        keep_offsets=keep_offsets,
    )
    plant = Plant(sc)
    result = simulate(plant, commands=np.zeros(plant.steps))
    steps = result.sensor_step
    truth = result.actuator_temperature[steps]
    positions = (
        actuator_positions(sc.rows, sc.cols)
        if sc.sensors.positions is None
        else np.asarray(sc.sensors.positions, float)
    )
    lag = sc.effects.sensor_lag
    base = EstimatorConfig(
        rows=sc.rows,
        cols=sc.cols,
        positions=positions,
        sample_period=1.0 / sc.sensor_rate,
        lowpass_cutoff_hz=DEFAULT_CUTOFF_HZ / sc.time_scale,
        sensor_tau=lag.tau_s if lag.enabled else 0.0,
        network=misjudged(NetworkParams(**asdict(sc.thermal)), error, pattern),
        tuning=KalmanTuning(sensor_noise=max(noise, 1e-4)).time_scaled(sc.time_scale),
    )
    skip = len(steps) // 10
    out: dict[str, float] = {"temperature_span": float(np.ptp(truth))}
    for kind in ("model", "lowpass"):
        run = replay(replace(base, kind=kind), result.sensor_time, result.temperature_raw,
                     result.heat_load[steps])
        stats = score(run.estimates, truth, base.sample_period, skip=skip,
                      max_lag=60.0 * sc.time_scale)
        out[f"thermal_rms_{kind}"] = stats.rms
        out[f"thermal_max_{kind}"] = stats.max
        out[f"thermal_lag_{kind}"] = stats.lag
        out[f"thermal_update_ms_{kind}"] = 1e3 * float(np.mean(run.update_seconds[1:]))
    return out


#: The estimators :func:`stage_steps` compares: the thesis's low-pass; the model estimator
#: without the sensor's lag (a thermal node that never heard of it: the lag left to the
#: feedforward's lead); with the lag as a state of its model; with the lag and the
#: stage-step gain (``model.step_gate``).
STEP_ESTIMATORS: tuple[str, ...] = ("lowpass", "model_no_lag", "model_lag", "model_steps")
#: The stage-step gate of ``model_steps`` [standard deviations of the mean innovation].
STEP_GATE = 4.0
#: Error bound of the settling time [degC].
SETTLED_WITHIN = 0.2


def stage_steps(lag_s: float = 0.0, *, scenario: str = "thesis_ac") -> dict[str, float]:
    """Score the estimators on a scenario's stage (base-plate) steps; return the figures.

    ``thesis_ac``: one actuator, the stage stepped 40 -> 52 degC in 2 degC steps, 150 s per
    level (physical), the NTC chain's noise (0.02 degC rms, 0.01 degC resolution), no heat
    load; ``lag_s`` is the sensor's lag [s, physical] (0: none; the scenario's own 3 s lag
    is replaced). Every estimator is told the network exactly; the ones with the lag get
    the simulator's. Each level is scored after its step (the first level has no step):
    per estimator ``<name>_step_max`` (largest error in the first half of a level),
    ``<name>_step_rms`` (rms error over the first fifth of a level, 30 s physical),
    ``<name>_settle_s`` (physical s after a step until the error stays within
    :data:`SETTLED_WITHIN`, the longest over the steps) and ``<name>_steady_rms`` (rms error
    over the last 30 % of every level: the steady state), all degC unless named.
    """
    sc = load_scenario(scenario).with_overrides(effects={"sensor_lag": lag_s > 0.0})
    ts = sc.time_scale
    if lag_s > 0.0:
        settings = tuple(
            s.with_values(tau_s=lag_s * ts) if s.name == "sensor_lag" else s
            for s in sc.effects.settings
        )
        sc = replace(sc, effects=replace(sc.effects, settings=settings))
    plant = Plant(sc)
    result = simulate(plant, commands=np.zeros(plant.steps))
    steps = result.sensor_step
    truth = result.actuator_temperature[steps]
    times = result.sensor_time
    tuning = KalmanTuning(sensor_noise=max(sc.sensors.noise_sd, 1e-6)).time_scaled(ts)
    base = EstimatorConfig(
        rows=sc.rows,
        cols=sc.cols,
        positions=actuator_positions(sc.rows, sc.cols),
        sample_period=1.0 / sc.sensor_rate,
        lowpass_cutoff_hz=DEFAULT_CUTOFF_HZ / ts,
        network=NetworkParams(**asdict(sc.thermal)),
        tuning=tuning,
    )
    configs = {
        "lowpass": replace(base, kind="lowpass"),
        "model_no_lag": base,
        "model_lag": replace(base, sensor_tau=lag_s * ts),
        "model_steps": replace(
            base, sensor_tau=lag_s * ts,
            tuning=replace(tuning, step_gate=STEP_GATE),
        ),
    }
    starts = sc.base.times[1:]  # scaled s: the steps
    level = starts[1] - starts[0]
    since_step = times - starts[0]
    phase = np.mod(since_step, level)
    stepped = since_step >= 0.0
    out: dict[str, float] = {"lag_s": lag_s}
    for name in STEP_ESTIMATORS:
        run = replay(configs[name], times, result.temperature_raw, result.heat_load[steps])
        err = np.abs(run.estimates - truth).reshape(len(times), -1).max(axis=1)
        out[f"{name}_step_max"] = float(np.max(err[stepped & (phase < 0.5 * level)]))
        transient = err[stepped & (phase < 0.2 * level)]
        steady = err[stepped & (phase > 0.7 * level)]
        out[f"{name}_step_rms"] = float(np.sqrt(np.mean(transient**2)))
        out[f"{name}_steady_rms"] = float(np.sqrt(np.mean(steady**2)))
        settle = 0.0
        for start in starts:
            window = (times >= start) & (times < start + level)
            off = np.flatnonzero(err[window] > SETTLED_WITHIN)
            if off.size:
                settle = max(settle, float(times[window][off[-1]] - start + base.sample_period))
        out[f"{name}_settle_s"] = settle / ts
    return out


def update_cost(
    rows: int, cols: int, pitch: int, *, sensor_tau: float = 0.0, updates: int = 200
) -> dict[str, float]:
    """Return the model estimator's build time [s] and time per update [ms].

    R x C grid, one sensor per ``pitch`` x ``pitch`` block, the simulator's thermal defaults,
    physical time, 10 Hz; the update figures are median, min and max over ``updates``.
    """
    positions = block_centre_positions(rows, cols, pitch)
    config = EstimatorConfig(rows, cols, positions, sensor_tau=sensor_tau)
    started = time.perf_counter()
    est = TemperatureEstimator(config)
    build = time.perf_counter() - started
    rng = np.random.default_rng(0)
    heat = np.full((rows, cols), 0.01)
    est.update(0.0, np.full(len(positions), 40.0))
    spent = []
    for k in range(1, updates + 1):
        readings = 40.0 + 0.01 * rng.standard_normal(len(positions))
        started = time.perf_counter()
        est.set_heat_load(heat)
        est.update(0.1 * k, readings)
        spent.append(time.perf_counter() - started)
    ms = 1e3 * np.asarray(spent)
    return {
        "build_s": build,
        "update_ms_median": float(np.median(ms)),
        "update_ms_min": float(np.min(ms)),
        "update_ms_max": float(np.max(ms)),
    }


#: Grids whose estimator build and update are timed in the thermal node's configuration.
NODE_COST_GRIDS: tuple[int, ...] = (32, 64)


def node_cost(rows: int, cols: int, *, updates: int = 200) -> dict[str, float]:
    """Return the build time [s] and time per update [ms] of the estimator the node builds.

    The configuration is the thermal node's for the lockstep benchmark: its parameter
    defaults (one sensor per actuator) with the ``dm_exposure`` scenario's values for an
    R x C grid (es_bringup.bringup.scenario_parameters), through the node's own mapping
    (``config_from_parameters``). An update is a heat load plus a message of readings, as
    the node hands them over; median, min and max over ``updates``.
    """
    from es_bringup.bringup import scenario_parameters
    from es_thermal.node_params import SPECS, config_from_parameters

    values: dict[str, object] = {spec.name: spec.default for spec in SPECS}
    values.update(scenario_parameters("dm_exposure", {"rows": rows, "cols": cols})[0])
    config = config_from_parameters(values)
    started = time.perf_counter()
    est = TemperatureEstimator(config)
    build = time.perf_counter() - started
    rng = np.random.default_rng(0)
    count = config.sensor_count
    heat = np.full((rows, cols), 0.01)
    est.update(0.0, np.full(count, 42.0))
    spent = []
    for k in range(1, updates + 1):
        readings = 42.0 + 0.02 * rng.standard_normal(count)
        started = time.perf_counter()
        est.set_heat_load(heat)
        est.update(config.sample_period * k, readings)
        spent.append(time.perf_counter() - started)
    ms = 1e3 * np.asarray(spent)
    return {
        "build_s": build,
        "update_ms_median": float(np.median(ms)),
        "update_ms_min": float(np.min(ms)),
        "update_ms_max": float(np.max(ms)),
    }


def main() -> None:
    """Print the figures of one accuracy run as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="dm_exposure")
    parser.add_argument("--pitch", type=int, default=2)
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--error", type=float, default=0.2)
    parser.add_argument("--pattern", default="mixed", choices=("mixed", "high", "low", "exact"))
    parser.add_argument("--duration", type=float, default=None, help="sim seconds")
    parser.add_argument("--time-scale", type=float, default=None)
    parser.add_argument("--sensor-rate", type=float, default=None, help="Hz")
    parser.add_argument("--sensor-lag", action="store_true", help="simulate sensor lag")
    parser.add_argument("--offsets", action="store_true", help="keep the sensor offsets")
    parser.add_argument(
        "--steps", action="store_true",
        help="instead: the estimate's error on the thesis_ac stage steps (see --lag)",
    )
    parser.add_argument(
        "--lag", type=float, default=0.0, help="with --steps: the sensor's lag, physical s"
    )
    parser.add_argument(
        "--cost", metavar="RxC/P", help="instead: time the model estimator, e.g. 32x32/2"
    )
    parser.add_argument(
        "--node-cost", metavar="RxC",
        help="instead: time the estimator as the thermal node builds it for dm_exposure",
    )
    args = parser.parse_args()
    if args.steps:
        print(json.dumps(stage_steps(args.lag), indent=2))
        return
    if args.node_cost:
        rows, cols = (int(v) for v in args.node_cost.split("x"))
        print(json.dumps(node_cost(rows, cols), indent=2))
        return
    if args.cost:
        size, pitch = args.cost.split("/")
        rows, cols = (int(v) for v in size.split("x"))
        print(json.dumps(update_cost(rows, cols, int(pitch)), indent=2))
        return
    figures = thermal_accuracy(
        args.scenario, pitch=args.pitch, noise=args.noise, error=args.error,
        pattern=args.pattern, duration=args.duration, time_scale=args.time_scale,
        sensor_rate=args.sensor_rate, effects={"sensor_lag": True} if args.sensor_lag else None,
        keep_offsets=args.offsets,
    )
    print(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
