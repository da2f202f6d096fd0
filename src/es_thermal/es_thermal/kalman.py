"""Model-based temperature estimator: a steady-state Kalman filter on the thermal network.

The network (:mod:`es_thermal.network`) is driven by the known heat load, so the estimate
follows heating without the lag of a low-pass filter; the sensors correct what the model gets
wrong (its parameters are never exactly the mirror's, and the base-plate temperature is not
measured at all). Sensor lag is part of the model: each sensor's own temperature is a state,
a first-order lag (one time constant per sensor) of the actuator field at its position, and
the readings measure those states. The filter so undoes the lag with the noise model (the
gain weighs the lag's inversion against the sensor noise), and the estimate is of the
actuator, not of the lagging sensor; nothing differentiates a reading.

Stage steps (optional, ``KalmanTuning.step_gate``): the base plate is a slow random walk in
the model, right for a temperature-controlled stage at a set point, too slow for a stage
stepped to a new set point, which the steady-state filter then follows only after seconds.
With the gate on, a sample whose mean innovation of the sensors (a stage step moves every
sensor alike) exceeds ``step_gate`` standard deviations is taken as a stage step of unknown
size (``step_size``, 1 sigma): the base plate's variance is raised by its square and the
filter runs the time-varying gains of that covariance (precomputed, :func:`modal.jump_gains`)
until they are the steady-state gain again. These weigh the lag's inversion against the
noise sample by sample, so the estimate neither rings nor is left with a residual when the
step is over. The gate is not watched meanwhile, and the model-error fit pauses: a stage
step is no model error. (Behind a lagging sensor, a fixed "fast base plate" gain for a fixed
window, the earlier scheme, amplified the noise through the lag's inversion while it was on
and left a residual that the quiet gain removed only slowly.)

Everything that does not depend on the data is computed once: the zero-order-hold
discretisation (matrix exponential) and the steady-state gain (discrete algebraic Riccati
equation solved by the structure-preserving doubling algorithm). The filter runs in modal
coordinates (2-D DCT of the grid and of a regular sensor grid), where the uniform network falls
apart into small independent groups of states (:mod:`es_thermal.modal`): the transition
matrix and the gain are then sparse with a few entries per state, and only the heat load and
readings in and the estimate out are transformed (fast DCT, O(N log N)). Nothing N x N is
ever formed. An irregular sensor layout keeps the sensors as they are and makes the gain
dense (S x S per group of coupled modes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Final

import numpy as np
from scipy import sparse

from es_common.arrays import BoolArray, FloatArray
from es_thermal.errors import EstimatorStateError, ThermalConfigError, ThermalInputError
from es_thermal.interpolation import sparse_sampling
from es_thermal.modal import ModalSolution, jump_gains, modal_solution
from es_thermal.network import (
    GridTransform,
    NetworkParams,
    StateLayout,
    lag_states,
    modal_model,
    sensor_lags,
    sensor_transform,
)

#: Sensor-transform columns formed at a time for the innovation weights (bounds memory).
_WEIGHT_CHUNK: Final = 256
#: Innovations and sensitivities enter the model-error fit clipped to +- this [degC, degC per
#: unit relative error]: far beyond any real temperature error, so only a wrecked state or an
#: absurd input reaches it, and one such sample cannot overflow the fit.
BIAS_FIT_LIMIT: Final = 1e3


@dataclass(frozen=True)
class KalmanTuning:
    """Noise levels the filter assumes.

    Attributes:
        sensor_noise: rms noise of one sensor reading [degC].
        process_noise: model error of every cell temperature, as a random-walk intensity
            [degC/sqrt(s)]; larger trusts the sensors more, smaller the model.
        base_drift: random-walk intensity of the unmeasured base-plate temperature
            [degC/sqrt(s)].
        adaptation_time: memory of the model-error estimates [s] (older data fade out).
        bias_prior: how far off the model is expected to be (relative, 1 sigma).
        bias_limit: the model-error estimates are clipped to +- this (relative).
        step_gate: stage-step tracking: the sensors' mean innovation, in its standard
            deviations, beyond which a stage step is followed (0: off, the filter has its
            steady-state gain only).
        step_size: the size of a stage step the filter expects, 1 sigma [degC].

    """

    sensor_noise: float = 0.01
    process_noise: float = 3e-3
    base_drift: float = 2e-2
    adaptation_time: float = 60.0
    bias_prior: float = 0.3
    bias_limit: float = 0.6
    step_gate: float = 0.0
    step_size: float = 1.0

    def __post_init__(self) -> None:
        """Check the values.

        Raises:
            ThermalConfigError: a value out of range (the message names it).

        """
        for name in (
            "sensor_noise", "process_noise", "base_drift", "adaptation_time", "bias_prior",
            "bias_limit", "step_size",
        ):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0.0:
                raise ThermalConfigError(f"{name}={value} must be finite and > 0")
        if not np.isfinite(self.step_gate) or self.step_gate < 0.0:
            raise ThermalConfigError(f"step_gate={self.step_gate} must be finite and >= 0")

    def time_scaled(self, time_scale: float) -> KalmanTuning:
        """Return the tuning for a run whose slow times are multiplied by ``time_scale``.

        The same random-walk spread over a time ``time_scale`` times as long needs
        intensities ``1/sqrt(time_scale)`` times as large (a step's size is a temperature,
        unchanged).
        """
        rate = 1.0 / np.sqrt(time_scale)
        return replace(
            self,
            process_noise=self.process_noise * rate,
            base_drift=self.base_drift * rate,
            adaptation_time=self.adaptation_time * time_scale,
        )


class ModelEstimator:
    """Steady-state Kalman filter on the thermal network, plus model-error estimation.

    The thermal parameters are never exactly the mirror's. Two errors matter most and are
    estimated on line as constant (slowly forgotten) relative biases, by Friedland's
    two-stage ("separate bias") scheme: the steady-state filter runs as if the model were
    right, and a small least-squares estimator fits the biases to its innovations through
    the state's sensitivity to them:

    - ``heat_gain``: the absorbed power heats the mirror (1 + b) times as much as the model
      says (wrong conductances, absorption or capacitances all scale the steady heating);
    - ``time_scale``: the network's response to the heat load is (1 + b) times as fast
      (wrong time constants); its sensitivity is built from the open-loop heat response, so
      that fixed sensor offsets, which the filter keeps correcting, do not pass for it.

    Cost per update: one sparse product with four columns (state, two sensitivities, heat
    response), one sparse gain product, and separable transforms of the heat load, the
    readings and the estimate.

    Args:
        rows, cols: actuator grid.
        positions: sensor (row, col) positions (S, 2) (:mod:`es_thermal.interpolation`).
        params: the network's parameters as the estimator believes them.
        sensor_tau: first-order sensor lag [s], one for all sensors or one per sensor (S,)
            (0: none). Lags that differ between sensors keep the sensors in their own
            coordinates, as an irregular layout does (a denser gain, a longer build).
        sample_period: the sensor sample period the filter is discretised for [s].
        tuning: assumed noise levels and how the model error is tracked.

    """

    BIASES: Final = ("heat_gain", "time_scale")

    def __init__(
        self,
        rows: int,
        cols: int,
        positions: FloatArray,
        *,
        params: NetworkParams,
        sensor_tau: float | FloatArray,
        sample_period: float,
        tuning: KalmanTuning,
    ) -> None:
        """Build the filter on the network for the sensors, ``sample_period`` [s] and ``tuning``.

        Raises:
            ThermalConfigError: a value out of range (the message names it).

        """
        if sample_period <= 0.0:
            raise ThermalConfigError(f"sample_period must be > 0, got {sample_period}")
        taus = sensor_lags(sensor_tau, positions.shape[0])
        lags = lag_states(taus, sample_period)
        self._grid = GridTransform.dct(rows, cols)
        self._sensors = (
            sensor_transform(positions)
            if lags is None or np.ptp(lags) == 0.0
            else GridTransform.eye(positions.shape[0])
        )
        A, B, H, layout = modal_model(params, rows, cols, positions, lags, sensors=self._sensors)
        q = np.zeros(layout.size)
        q[layout.face] = tuning.process_noise**2
        q[layout.actuator] = tuning.process_noise**2
        q[layout.sensor] = (1e-3 * tuning.process_noise) ** 2  # lag model taken as known
        q[layout.base] = tuning.base_drift**2

        # Every noise is isotropic within its group of states, so it looks the same in modes.
        def solve(q: FloatArray) -> ModalSolution:
            return modal_solution(
                A, B, H, q=q * sample_period, r=tuning.sensor_noise**2, dt=sample_period
            )

        modal = solve(q)
        # The sensors' mean innovation: its weights in sensor modes and its standard deviation.
        self._mean_weights = self._sensors.forward(np.full(positions.shape[0], 1.0))
        self._mean_weights /= positions.shape[0]

        def mean_sd(solution: ModalSolution) -> float:
            spread = self._mean_weights @ (solution.innovation_cov @ self._mean_weights)
            return float(np.sqrt(spread))

        self._mean_sd = mean_sd(modal)
        self._jump: tuple[sparse.csr_matrix, ...] | None = None
        if tuning.step_gate > 0.0:
            self._jump = jump_gains(
                modal.A_d, H, q=q * sample_period, r=tuning.sensor_noise**2,
                state=layout.base, variance=tuning.step_size**2,
            )  # fmt: skip
        self._jump_sample = self._jump_length  # samples since a step was detected
        self.layout: StateLayout = layout
        self.sampling: sparse.csr_matrix = sparse_sampling(rows, cols, positions)
        self.tuning = tuning
        self.sample_period = sample_period
        self._A = modal.A_d
        self._B = modal.B_d
        self._H = H
        self._gain = modal.gain
        # Innovation weights of the bias fit (diagonal: a sensor subset needs no inversion).
        self._innovation_weight: FloatArray = 1.0 / self._sensor_diagonal(modal.innovation_cov)
        self._thermal = slice(0, 2 * layout.cells)
        # The state, its sensitivities and the heat response are kept in modes.
        self._state: FloatArray | None = None
        nb = len(self.BIASES)
        self._prior_info = np.eye(nb) / tuning.bias_prior**2
        self._sens = np.zeros((layout.size, nb))  # d(state)/d(bias), posterior
        self._heat_response = np.zeros(layout.size)  # open-loop response to the heat load
        self._info = self._prior_info.copy()
        self._info_vector = np.zeros(nb)
        self._bias = np.zeros(nb)

    @property
    def initialised(self) -> bool:
        """True once the state was set from a first set of readings."""
        return self._state is not None

    @property
    def base_temperature(self) -> float:
        """The current base-plate estimate [degC] (NaN before initialisation)."""
        if self._state is None:
            return float("nan")
        base = self.layout.base
        return float(self._state[base] + self._sens[base] @ self._bias)

    @property
    def _jump_length(self) -> int:
        return 0 if self._jump is None else len(self._jump)

    @property
    def following_step(self) -> bool:
        """True while a stage step is followed with its gains (``step_gate`` on)."""
        return self._jump_sample < self._jump_length

    @property
    def biases(self) -> dict[str, float]:
        """The current model-error estimates by name (relative, 0 = the model is right)."""
        return {name: float(b) for name, b in zip(self.BIASES, self._bias, strict=True)}

    def actuator_temperatures(self) -> FloatArray:
        """Return the current estimate of every actuator temperature, flat (N,)."""
        act = self.layout.actuator
        x = self._require_state()
        return self._grid.inverse(x[act] + self._sens[act] @ self._bias)

    def gain_matrix(self) -> FloatArray:
        """Return the steady-state Kalman gain in grid coordinates, dense (states x S).

        For inspection and tests: it is formed from the modal gain, O(states x S) memory.
        """
        modal = self._sensors.inverse(self._gain.toarray().T).T
        return self._from_modes(modal)

    def initialise(self, field: FloatArray, readings: FloatArray, valid: BoolArray) -> None:
        """Start from an equilibrium at ``field`` (N,), the actuator field the readings suggest.

        Valid readings seed the lag states of their sensors; the base plate starts at the
        mean valid reading. The model-error estimates restart from zero.
        """
        lay = self.layout
        x = np.empty(lay.size)
        x[lay.face] = field
        x[lay.actuator] = field
        if lay.sensors:
            x[lay.sensor] = np.where(valid, readings, self.sampling @ field)
        x[lay.base] = float(np.mean(readings[valid]))
        self._state = self._to_modes(x)
        self._sens[:] = 0.0
        # The heat-driven response alone, from a uniform start: what a faster network would
        # speed up. (The filter's own state also relaxes its corrections, which would make
        # fixed sensor offsets look like a time-scale error.)
        self._heat_response[:] = 0.0
        self._info = self._prior_info.copy()
        self._info_vector[:] = 0.0
        self._bias[:] = 0.0
        self._jump_sample = self._jump_length

    def predict(self, heat_load: FloatArray, steps: int = 1) -> None:
        """Advance the model ``steps`` sample periods with the heat load (N,) held.

        Raises:
            ThermalInputError: the heat load holds NaN or inf (the state is left as it was).

        """
        x = self._require_state()
        if not np.all(np.isfinite(heat_load)):
            raise ThermalInputError("heat load holds NaN or inf")
        drive = np.asarray(self._B @ self._grid.forward(heat_load))
        # One sparse product advances the state, both sensitivities and the heat response.
        cols = np.column_stack([x, self._sens, self._heat_response])
        thermal = self._thermal
        for _ in range(steps):
            nxt = np.asarray(self._A @ cols)
            nxt[:, 0] += drive
            nxt[:, 3] += drive
            # Sensitivities: more heat -> more of the heat drive; faster -> more of the
            # heat response's step (only the thermal nodes speed up, not the sensor lag).
            nxt[:, 1] += drive
            nxt[thermal, 2] += nxt[thermal, 3] - cols[thermal, 3]
            cols = nxt
        self._state = cols[:, 0].copy()
        self._sens = cols[:, 1:3].copy()
        self._heat_response = cols[:, 3].copy()

    def correct(self, readings: FloatArray, valid: BoolArray) -> FloatArray:
        """Correct the predicted state with the valid readings; return the innovations.

        Invalid sensors get a zero innovation: their gain columns are left out. With
        ``step_gate`` on, a stage step is followed with its gains (module docstring).
        """
        x = self._require_state()
        seen = self._sensors.inverse(np.asarray(self._H @ np.column_stack([x, self._sens])))
        innovation = np.where(valid, readings - seen[:, 0], 0.0)
        regressor = seen[:, 1:]
        regressor[~valid] = 0.0
        modal = self._sensors.forward(np.column_stack([innovation, -regressor]))
        if not self.following_step and self._is_stage_step(modal[:, 0], valid):
            self._jump_sample = 0
        # One pass over the (sparse, modal) gain corrects the state and the sensitivities.
        update = np.asarray(self._gain @ modal)
        if self._jump is not None and self.following_step:
            update += np.asarray(self._jump[self._jump_sample] @ modal)
            self._jump_sample += 1
            self._state = x + update[:, 0]
            self._sens = self._sens + update[:, 1:]
            return innovation  # a stage step is no model error: the fit pauses
        self._state = x + update[:, 0]
        self._sens = self._sens + update[:, 1:]
        self._fit_biases(
            np.clip(innovation, -BIAS_FIT_LIMIT, BIAS_FIT_LIMIT),
            np.clip(regressor, -BIAS_FIT_LIMIT, BIAS_FIT_LIMIT),
        )
        return innovation

    def _is_stage_step(self, modal_innovation: FloatArray, valid: BoolArray) -> bool:
        """Return whether the sensors' mean innovation stands out as a stage step.

        ``modal_innovation`` is the innovation in sensor modes (invalid sensors at 0); the
        mean over fewer valid sensors has a proportionally larger spread. Always False with
        ``step_gate`` off.
        """
        count = int(np.count_nonzero(valid))
        if self._jump is None or count == 0:
            return False
        share = count / valid.size
        z = abs(float(self._mean_weights @ modal_innovation)) / share
        return z > self.tuning.step_gate * self._mean_sd / np.sqrt(share)

    def _fit_biases(self, innovation: FloatArray, regressor: FloatArray) -> None:
        """Update the model-error estimates by least squares pulled towards zero bias.

        Old data are forgotten exponentially (``adaptation_time``). A step whose fit is not
        finite or singular (only after an absurd input) is skipped: the previous fit and
        estimates are kept.
        """
        forget = np.exp(-self.sample_period / self.tuning.adaptation_time)
        weighted = regressor * self._innovation_weight[:, None]
        info = forget * self._info + (1 - forget) * self._prior_info + regressor.T @ weighted
        info_vector = forget * self._info_vector + weighted.T @ innovation
        try:
            bias = np.linalg.solve(info, info_vector)
        except np.linalg.LinAlgError:
            return
        if not np.all(np.isfinite(bias)):
            return
        self._info, self._info_vector = info, info_vector
        self._bias = np.clip(bias, -self.tuning.bias_limit, self.tuning.bias_limit)

    def _require_state(self) -> FloatArray:
        if self._state is None:
            raise EstimatorStateError("the model estimator has no state yet")
        return self._state

    def _sensor_diagonal(self, modal: sparse.csr_matrix) -> FloatArray:
        """Return diag(Ts' M Ts) of a sensor-mode matrix M (S x S), in sensor order (S,)."""
        count = modal.shape[0]
        out = np.empty(count)
        for start in range(0, count, _WEIGHT_CHUNK):
            index = np.arange(start, min(start + _WEIGHT_CHUNK, count))
            columns = self._sensors.columns(index)
            out[index] = np.sum(columns * np.asarray(modal @ columns), axis=0)
        return out

    def _to_modes(self, x: FloatArray) -> FloatArray:
        """Return a grid-coordinate state (states,) or (states, k) in modes."""
        return self._map(x, GridTransform.forward)

    def _from_modes(self, x: FloatArray) -> FloatArray:
        """Return a modal state (states,) or (states, k) in grid coordinates."""
        return self._map(x, GridTransform.inverse)

    def _map(
        self, x: FloatArray, apply: Callable[[GridTransform, FloatArray], FloatArray]
    ) -> FloatArray:
        lay = self.layout
        out = np.array(x, float)
        out[lay.face] = apply(self._grid, x[lay.face])
        out[lay.actuator] = apply(self._grid, x[lay.actuator])
        if lay.sensors:
            out[lay.sensor] = apply(self._sensors, x[lay.sensor])
        return out
