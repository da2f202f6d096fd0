"""Score an estimator offline against known actuator temperatures (a simulation's truth).

:func:`replay` feeds recorded sensor samples (and heat loads) through a
:class:`~es_thermal.estimator.TemperatureEstimator` exactly as the node would;
:func:`score` compares the estimates with the true actuator temperatures: RMS and largest
error, and the lag, the time shift of the truth that best matches the estimate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from es_common.arrays import FloatArray
from es_thermal.errors import ThermalInputError
from es_thermal.estimator import EstimatorConfig, TemperatureEstimator


@dataclass(frozen=True)
class Replay:
    """Estimates of a replayed run: (K, R, C), NaN where no estimate was published."""

    estimates: FloatArray
    update_seconds: FloatArray  # wall time of each update (K,)


@dataclass(frozen=True)
class ErrorStats:
    """Estimation error over the scored samples [degC], and the estimate's lag [s]."""

    rms: float
    max: float
    lag: float
    samples: int


def replay(
    config: EstimatorConfig,
    times: FloatArray,
    readings: FloatArray,
    heat_loads: FloatArray | None = None,
) -> Replay:
    """Run a fresh estimator over K samples as the node would.

    Args:
        config: the estimator to build.
        times: sample times (K,) [s].
        readings: sensor readings (K, S) [degC].
        heat_loads: the heat load published at each sample time (K, R, C) [W], if known.

    """
    est = TemperatureEstimator(config)
    out = np.full((len(times), config.rows, config.cols), np.nan)
    spent = np.zeros(len(times))
    for k, (t, y) in enumerate(zip(times, readings, strict=True)):
        started = time.perf_counter()
        if heat_loads is not None:
            est.set_heat_load(heat_loads[k])
        result = est.update(float(t), y)
        spent[k] = time.perf_counter() - started
        if result.temperatures is not None:
            out[k] = result.temperatures
    return Replay(out, spent)


def score(
    estimates: FloatArray,
    truth: FloatArray,
    sample_period: float,
    skip: int = 0,
    max_lag: float = 30.0,
) -> ErrorStats:
    """Compare estimates with the truth (both (K, R, C)).

    The first ``skip`` samples and samples without an estimate are left out. The lag is the
    shift (0 .. ``max_lag`` s, whole samples) of the truth that minimises the RMS difference.

    Raises:
        ThermalInputError: no sample has an estimate.

    """
    est = estimates[skip:]
    true = truth[skip:]
    used = ~np.isnan(est).any(axis=(1, 2))
    err = (est - true)[used]
    if err.size == 0:
        raise ThermalInputError("no estimate to score")
    shifts = range(min(round(max_lag / sample_period), len(est) // 2) + 1)
    # RMS difference between the estimate at t and the truth at t - shift.
    rms_at = [
        float(np.sqrt(np.nanmean((est[s:] - true[: len(true) - s]) ** 2))) for s in shifts
    ]
    return ErrorStats(
        rms=float(np.sqrt(np.mean(err**2))),
        max=float(np.max(np.abs(err))),
        lag=float(np.argmin(rms_at)) * sample_period,
        samples=int(np.count_nonzero(used)),
    )
