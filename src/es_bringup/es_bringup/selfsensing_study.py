"""What self-sensing buys: temperature error and feedforward variation, offline (pure).

Three ways to know the actuator temperatures on the same mirror and exposure (plant core,
thermal estimator core and feedforward core in closed loop, no DDS):

- ``ntc``: a few NTCs (one per ``pitch`` x ``pitch`` block, default 4 on 12 x 12) and the
  thermal model (the thermal node as today);
- ``ntc_selfsensing``: the same plus every actuator's resonance reading, fused per actuator
  (:class:`es_thermal.selfsensing.SelfSensingFusion`) with the laws calibrated from an
  offline characterisation run (:func:`characterise`: the test-stand scenario with the
  resonance measurement on, fitted by :func:`es_thermal.resonance_calibration.fit_resonance`);
- ``sensor_per_actuator``: an NTC on every actuator and the thermal model.

Each case reports the per-actuator RMS temperature error map (the first
:data:`SKIP_FRACTION` of the run, the start-up, is not scored), its RMS over the grid, the
worst actuator's RMS, the largest single error, and the feedforward's temperature-induced
variation (:func:`es_bringup.metrics.run_metrics`). The feedforward uses the simulator's
true actuator laws, so that the variation shows only what the temperature estimate adds.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Final

import numpy as np

from es_bringup.metrics import AlignedRun, run_metrics
from es_common.arrays import FloatArray
from es_feedforward.feedforward import Feedforward, FeedforwardConfig
from es_sim_plant.errors import SimulationInputError
from es_sim_plant.plant import Observation, Plant, simulate
from es_sim_plant.resonance import ResonanceConfig
from es_sim_plant.scenario import Scenario, load_scenario
from es_thermal.estimator import EstimatorConfig, TemperatureEstimator
from es_thermal.interpolation import actuator_positions, block_centre_positions
from es_thermal.kalman import KalmanTuning
from es_thermal.network import NetworkParams
from es_thermal.resonance_calibration import ResonanceFit, fit_resonance
from es_thermal.selfsensing import FusionConfig, ResonanceCalibration, SelfSensingFusion

CASES: Final = ("ntc", "ntc_selfsensing", "sensor_per_actuator")
#: Human-readable case names (report and bench).
CASE_TITLES: Final = {
    "ntc": "(a) NTCs only",
    "ntc_selfsensing": "(b) NTCs + self-sensing",
    "sensor_per_actuator": "(c) a sensor on every actuator",
}
#: Start-up share of a run left out of the temperature scores.
SKIP_FRACTION: Final = 0.1
#: Set-point period of the variation [s] (the scenarios' 1 Hz sine).
PERIOD_S: Final = 1.0


@dataclass(frozen=True)
class CaseResult:
    """Figures of one case.

    Attributes:
        name: one of :data:`CASES`.
        rms_map: per-actuator RMS temperature error (R, C) [degC].
        rms: RMS error over every actuator and scored sample [degC].
        worst: the largest per-actuator RMS error [degC].
        max_error: the largest single error [degC].
        variation_m: the feedforward's temperature-induced variation [m].
        sensors: number of NTCs.

    """

    name: str
    rms_map: FloatArray
    rms: float
    worst: float
    max_error: float
    variation_m: float
    sensors: int


def characterise(
    resonance: ResonanceConfig | None = None,
    *,
    scenario: str = "characterisation",
    duration: float | None = None,
) -> ResonanceFit:
    """Run the test-stand scenario offline with the resonance measurement on; fit the laws.

    The stage temperature is the mean of the NTC readings, the voltage the command in force
    at each sweep (the previous step's), T0 the scenario's initial base temperature.
    """
    config = replace(resonance or ResonanceConfig(), enabled=True)
    sc = replace(load_scenario(scenario).with_overrides(duration=duration), resonance=config)
    plant = Plant(sc)
    result = simulate(plant)
    assert result.resonance is not None
    previous = np.maximum(result.sensor_step - 1, 0)
    voltage = np.where((result.sensor_step > 0)[:, None, None], result.command[previous], 0.0)
    stage = np.mean(result.temperature_raw, axis=1)
    return fit_resonance(
        result.sensor_time, result.resonance, voltage, stage, sc.initial_base_temperature
    )


def case_scenario(
    case: str,
    *,
    scenario: str = "dm_exposure",
    pitch: int = 6,
    resonance: ResonanceConfig | None = None,
    duration: float | None = None,
) -> Scenario:
    """Return the scenario of a case: ``pitch`` NTCs (or one per actuator), resonance on."""
    sc = load_scenario(scenario).with_overrides(duration=duration)
    positions = (
        None
        if case == "sensor_per_actuator"
        else tuple((float(r), float(c)) for r, c in block_centre_positions(sc.rows, sc.cols, pitch))
    )
    config = replace(resonance or ResonanceConfig(), enabled=True)
    return replace(sc, sensors=replace(sc.sensors, positions=positions), resonance=config)


def fusion_for(
    fit: ResonanceFit, time_scale: float, config: FusionConfig | None = None
) -> SelfSensingFusion:
    """Return the fusion the thermal node would build from ``fit`` (drift time-scaled)."""
    base = config or FusionConfig(noise_hz=fit.noise_hz)
    calibration = ResonanceCalibration.from_values(
        fit.f0_hz.size,
        f0_hz=fit.f0_hz,
        a_t_hz_per_degc=fit.a_t_hz_per_degc,
        a_v_hz_per_v=fit.a_v_hz_per_v,
        reference_temperature=fit.reference_temperature,
        f0_sd_hz=fit.f0_sd_hz,
        a_t_sd=fit.a_t_sd,
        a_v_sd=fit.a_v_sd,
    )
    return SelfSensingFusion(calibration, base.time_scaled(time_scale), fit.disabled)


def run_case(sc: Scenario, case: str, fit: ResonanceFit | None = None) -> CaseResult:
    """Run one case in closed loop offline and score it.

    Raises:
        SimulationInputError: ``ntc_selfsensing`` without a fit, or an unknown case.

    """
    if case not in CASES:
        raise SimulationInputError(f"unknown case {case!r}; one of {list(CASES)}")
    if case == "ntc_selfsensing" and fit is None:
        raise SimulationInputError("ntc_selfsensing needs a resonance calibration")
    plant = Plant(sc)
    positions = (
        actuator_positions(sc.rows, sc.cols)
        if sc.sensors.positions is None
        else np.asarray(sc.sensors.positions, float)
    )
    estimator = TemperatureEstimator(
        EstimatorConfig(
            rows=sc.rows,
            cols=sc.cols,
            positions=positions,
            sample_period=1.0 / sc.sensor_rate,
            network=NetworkParams(**asdict(sc.thermal)),
            tuning=KalmanTuning(sensor_noise=max(sc.sensors.noise_sd, 1e-4)).time_scaled(
                sc.time_scale
            ),
        )
    )
    fusion = (
        fusion_for(fit, sc.time_scale) if case == "ntc_selfsensing" and fit is not None else None
    )
    feedforward = Feedforward(FeedforwardConfig(shape=sc.shape, params=plant.true_params))
    estimates: list[FloatArray] = []
    truth: list[FloatArray] = []
    last = np.zeros(sc.shape)

    def controller(obs: Observation) -> FloatArray:
        nonlocal last
        if obs.temperature_raw is not None and obs.heat_load is not None:
            estimator.set_heat_load(obs.heat_load)
            temperature = estimator.update(obs.time, obs.temperature_raw).temperatures
            if temperature is not None:
                if fusion is not None:
                    fusion.set_command(last)
                    temperature = fusion.fuse(obs.time, temperature, obs.resonance)
                feedforward.update_temperature(temperature, obs.time)
                estimates.append(temperature)
                truth.append(plant.actuator_temperature().copy())
        last = np.asarray(feedforward.command(obs.setpoint, obs.time).voltage, float)
        return last

    result = simulate(plant, controller=controller)
    error = np.asarray(estimates) - np.asarray(truth)
    scored = error[int(SKIP_FRACTION * len(error)) :]
    rms_map = np.sqrt(np.mean(scored**2, axis=0))
    run = AlignedRun.of_simulation(result, plant.dt)
    metrics = run_metrics(run, PERIOD_S, skip_s=PERIOD_S)[0]
    return CaseResult(
        name=case,
        rms_map=rms_map,
        rms=float(np.sqrt(np.mean(scored**2))),
        worst=float(np.max(rms_map)),
        max_error=float(np.max(np.abs(scored))),
        variation_m=metrics.variation_m,
        sensors=len(positions),
    )


def study(
    *,
    scenario: str = "dm_exposure",
    pitch: int = 6,
    resonance: ResonanceConfig | None = None,
    duration: float | None = None,
    fit: ResonanceFit | None = None,
) -> dict[str, CaseResult]:
    """Run every case of :data:`CASES` on ``scenario``; calibrate first unless ``fit`` given."""
    calibration = fit if fit is not None else characterise(resonance)
    return {
        case: run_case(
            case_scenario(
                case, scenario=scenario, pitch=pitch, resonance=resonance, duration=duration
            ),
            case,
            calibration,
        )
        for case in CASES
    }
