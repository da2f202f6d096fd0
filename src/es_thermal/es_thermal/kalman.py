"""Model-based temperature estimator: a steady-state Kalman filter on the thermal network.

The network (:mod:`es_thermal.network`) is driven by the known heat load, so the estimate
follows heating without the lag of a low-pass filter; the sensors correct what the model gets
wrong (its parameters are never exactly the mirror's, and the base-plate temperature is not
measured at all). Sensor lag is part of the model, so the estimate is of the actuator, not of
the lagging sensor.

Everything that does not depend on the data is computed once: the zero-order-hold
discretisation (matrix exponential) and the steady-state gain (discrete algebraic Riccati
equation solved by the structure-preserving doubling algorithm). Both are computed in modal
coordinates (2-D DCT of the grid and of a regular sensor grid), where the uniform network falls
apart into small independent groups of states, then transformed back: about 0.1 s for a
12 x 12 grid and 2-3 s for 32 x 32 instead of minutes for the dense equation. An update is
then one sparse prediction and one dense gain product (about 0.1 ms at 12 x 12 and 1 ms at
32 x 32 with a sensor per 2 x 2 actuators, single-threaded BLAS).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy import linalg, sparse
from scipy.sparse import csgraph

from es_thermal.interpolation import sampling_matrix
from es_thermal.network import NetworkParams, StateLayout, grid_dct, modal_model, sensor_transform

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: Entries of the discretised transition matrix below this fraction of its largest entry are
#: dropped: heat spreads only a few cells per sample, so the matrix is nearly banded.
SPARSITY_THRESHOLD = 1e-13
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

    """

    sensor_noise: float = 0.01
    process_noise: float = 3e-3
    base_drift: float = 2e-2
    adaptation_time: float = 60.0
    bias_prior: float = 0.3
    bias_limit: float = 0.6

    def __post_init__(self) -> None:
        for name in (
            "sensor_noise", "process_noise", "base_drift", "adaptation_time", "bias_prior",
            "bias_limit",
        ):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0.0:
                raise ValueError(f"{name}={value} must be finite and > 0")

    def time_scaled(self, time_scale: float) -> KalmanTuning:
        """Return the tuning for a run whose slow times are multiplied by ``time_scale``.

        The same random-walk spread over a time ``time_scale`` times as long needs
        intensities ``1/sqrt(time_scale)`` times as large.
        """
        rate = 1.0 / np.sqrt(time_scale)
        return replace(
            self,
            process_noise=self.process_noise * rate,
            base_drift=self.base_drift * rate,
            adaptation_time=self.adaptation_time * time_scale,
        )


def discretise(
    A: FloatArray, B: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray]:
    """Return the zero-order-hold discretisation (A_d, B_d) of dx/dt = A x + B u over ``dt``."""
    n, m = B.shape
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n] = A * dt
    augmented[:n, n:] = B * dt
    phi = linalg.expm(augmented)
    return phi[:n, :n], phi[:n, n:]


def steady_state_covariance(
    A: FloatArray,
    H: FloatArray,
    Q: FloatArray,
    R: FloatArray,
    *,
    tol: float = 1e-12,
    max_iter: int = 80,
) -> FloatArray:
    """Return the steady-state prior covariance P of the Kalman filter for (A, H, Q, R).

    P solves the filter DARE ``P = A P A' - A P H' (H P H' + R)^-1 H P A' + Q``; the
    structure-preserving doubling algorithm gets there in a few dozen iterations
    (quadratic convergence) even when the slowest mode barely decays per sample.

    Raises:
        ValueError: no convergence (the pair (A, H) is not detectable).

    """
    n = A.shape[0]
    Ak = A.T.copy()
    Gk = H.T @ np.linalg.solve(R, H)
    Hk = Q.copy()
    eye = np.eye(n)
    for _ in range(max_iter):
        W = eye + Gk @ Hk
        Y = np.linalg.solve(W, np.hstack([Ak, Gk]))
        Y_a, Y_g = Y[:, :n], Y[:, n:]
        H_next = Hk + Ak.T @ Hk @ Y_a
        Gk = Gk + Ak @ Y_g @ Ak.T
        Ak = Ak @ Y_a
        change = np.max(np.abs(H_next - Hk))
        Hk = 0.5 * (H_next + H_next.T)
        if change <= tol * max(1.0, float(np.max(np.abs(Hk)))):
            return Hk
    raise ValueError("Kalman gain: the Riccati iteration did not converge")


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
    response) and one dense gain product.

    Args:
        rows, cols: actuator grid.
        positions: sensor (row, col) positions (S, 2) (:mod:`es_thermal.interpolation`).
        params: the network's parameters as the estimator believes them.
        sensor_tau: first-order sensor lag [s] (0: none).
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
        sensor_tau: float,
        sample_period: float,
        tuning: KalmanTuning,
    ) -> None:
        if sample_period <= 0.0 or sensor_tau < 0.0:
            raise ValueError("sample_period must be > 0 and sensor_tau >= 0")
        sampling = sampling_matrix(rows, cols, positions)
        to_sensor_modes = sensor_transform(positions)
        A, B, H, layout = modal_model(
            params, rows, cols, sampling, sensor_tau, sensors=to_sensor_modes
        )
        q = np.zeros(layout.size)
        q[layout.face] = tuning.process_noise**2
        q[layout.actuator] = tuning.process_noise**2
        q[layout.sensor] = (1e-3 * tuning.process_noise) ** 2  # lag model taken as known
        q[layout.base] = tuning.base_drift**2
        # Every noise is isotropic within its group of states, so it looks the same in modes.
        modal = _modal_solution(
            A, B, H, q=q * sample_period, r=tuning.sensor_noise**2, dt=sample_period
        )
        to_grid_modes = grid_dct(rows, cols)
        basis = [to_grid_modes, to_grid_modes] + ([to_sensor_modes] if layout.sensors else [])
        A_d = _to_grid(basis, modal.A_d @ sparse.block_diag([*basis, np.eye(1)]).toarray())
        B_d = _to_grid(basis, modal.B_d @ to_grid_modes)
        self.gain: FloatArray = _to_grid(basis, modal.gain @ to_sensor_modes)
        innovation_cov = to_sensor_modes.T @ modal.innovation_cov @ to_sensor_modes
        # Innovation weights of the bias fit (diagonal: a sensor subset needs no inversion).
        self._innovation_weight: FloatArray = 1.0 / np.diag(innovation_cov)
        H = np.zeros((sampling.shape[0], layout.size))
        if layout.sensors:
            H[:, layout.sensor] = np.eye(sampling.shape[0])
        else:
            H[:, layout.actuator] = sampling
        self.layout: StateLayout = layout
        self.sampling = sampling
        self.tuning = tuning
        self.sample_period = sample_period
        self._A = _sparsified(A_d)
        self._B = _sparsified(B_d)
        self._H = sparse.csr_matrix(H)
        self._thermal = slice(0, 2 * layout.cells)
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
        return float("nan") if self._state is None else float(self._estimate()[self.layout.base])

    @property
    def biases(self) -> dict[str, float]:
        """The current model-error estimates by name (relative, 0 = the model is right)."""
        return {name: float(b) for name, b in zip(self.BIASES, self._bias, strict=True)}

    def actuator_temperatures(self) -> FloatArray:
        """Return the current estimate of every actuator temperature, flat (N,)."""
        return self._estimate()[self.layout.actuator].copy()

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
        self._state = x
        self._sens[:] = 0.0
        # The heat-driven response alone, from a uniform start: what a faster network would
        # speed up. (The filter's own state also relaxes its corrections, which would make
        # fixed sensor offsets look like a time-scale error.)
        self._heat_response[:] = 0.0
        self._info = self._prior_info.copy()
        self._info_vector[:] = 0.0
        self._bias[:] = 0.0

    def predict(self, heat_load: FloatArray, steps: int = 1) -> None:
        """Advance the model ``steps`` sample periods with the heat load (N,) held.

        Raises:
            ValueError: the heat load holds NaN or inf (the state is left as it was).

        """
        x = self._require_state()
        if not np.all(np.isfinite(heat_load)):
            raise ValueError("heat load holds NaN or inf")
        drive = np.asarray(self._B @ heat_load)
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

        Invalid sensors get a zero innovation: their gain columns are left out.
        """
        x = self._require_state()
        seen = np.asarray(self._H @ np.column_stack([x, self._sens]))
        innovation = np.where(valid, readings - seen[:, 0], 0.0)
        regressor = seen[:, 1:]
        regressor[~valid] = 0.0
        # One pass over the (large, dense) gain corrects the state and the sensitivities.
        update = self.gain @ np.column_stack([innovation, -regressor])
        self._state = x + update[:, 0]
        self._sens = self._sens + update[:, 1:]
        self._fit_biases(
            np.clip(innovation, -BIAS_FIT_LIMIT, BIAS_FIT_LIMIT),
            np.clip(regressor, -BIAS_FIT_LIMIT, BIAS_FIT_LIMIT),
        )
        return innovation

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
            raise ValueError("the model estimator has no state yet")
        return self._state

    def _estimate(self) -> FloatArray:
        return self._require_state() + self._sens @ self._bias


@dataclass(frozen=True)
class _ModalSolution:
    """Discretised network and steady-state filter in modal coordinates."""

    A_d: sparse.csr_matrix
    B_d: sparse.csr_matrix
    gain: sparse.csr_matrix
    innovation_cov: FloatArray


def _modal_solution(
    A: FloatArray, B: FloatArray, H: FloatArray, *, q: FloatArray, r: float, dt: float
) -> _ModalSolution:
    """Discretise and solve the filter DARE block by block.

    In modal coordinates the network falls apart into independent groups of states and
    measurements (connected components of the coupling graph): each is discretised and
    solved on its own, which costs little even for a 32 x 32 grid. An irregular sensor
    layout couples everything into one group and this becomes the dense solution.
    """
    n, s = A.shape[0], H.shape[0]
    state_links = sparse.csr_matrix(A != 0.0)
    sensor_links = sparse.csr_matrix(H != 0.0)
    coupled = sparse.bmat([[state_links, sensor_links.T], [sensor_links, None]])
    _, label = csgraph.connected_components(coupled, directed=False)
    state_label, measurement_label = label[:n], label[n:]
    inputs = np.flatnonzero(np.any(B != 0.0, axis=0))
    A_d = sparse.lil_matrix((n, n))
    B_d = sparse.lil_matrix((n, B.shape[1]))
    gain = sparse.lil_matrix((n, s))
    innovation_cov = np.zeros((s, s))
    for group in np.unique(state_label):
        st = np.flatnonzero(state_label == group)
        ms = np.flatnonzero(measurement_label == group)
        cols = inputs[np.any(B[np.ix_(st, inputs)] != 0.0, axis=0)]
        Ad, Bd = discretise(A[np.ix_(st, st)], B[np.ix_(st, cols)], dt)
        A_d[np.ix_(st, st)] = Ad
        B_d[np.ix_(st, cols)] = Bd
        if ms.size == 0:
            continue  # unobserved and stable (the Laplacian's higher modes decay to the base)
        Hc = H[np.ix_(ms, st)]
        R = r * np.eye(ms.size)
        P = steady_state_covariance(Ad, Hc, np.diag(q[st]), R)
        cov = Hc @ P @ Hc.T + R
        gain[np.ix_(st, ms)] = np.linalg.solve(cov, Hc @ P).T
        innovation_cov[np.ix_(ms, ms)] = cov
    return _ModalSolution(A_d.tocsr(), B_d.tocsr(), gain.tocsr(), innovation_cov)


def _to_grid(basis: list[FloatArray], modal_rows: FloatArray | sparse.spmatrix) -> FloatArray:
    """Return T' X for the block-diagonal modal transform T = diag(basis..., 1)."""
    dense = modal_rows if isinstance(modal_rows, np.ndarray) else modal_rows.toarray()
    out = np.empty_like(dense)
    start = 0
    for block in basis:
        stop = start + block.shape[0]
        out[start:stop] = block.T @ dense[start:stop]
        start = stop
    out[start:] = dense[start:]
    return np.asarray(out, float)


def _sparsified(matrix: FloatArray) -> sparse.csr_matrix | FloatArray:
    """Drop negligible entries; keep the matrix dense if that does not make it sparse."""
    scale = float(np.max(np.abs(matrix))) if matrix.size else 0.0
    kept = np.where(np.abs(matrix) > SPARSITY_THRESHOLD * scale, matrix, 0.0)
    if np.count_nonzero(kept) > 0.25 * kept.size:
        return kept
    return sparse.csr_matrix(kept)
