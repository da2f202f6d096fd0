"""Thermal network of the mirror as the model-based estimator sees it.

Per actuator cell two nodes, the mirror face sheet above the actuator (it absorbs the UV
heat load) and the actuator itself, plus one base plate shared by all cells:

    C_f dT_f/dt = P - G_fa (T_f - T_a) - G_ff lap(T_f)
    C_a dT_a/dt = G_fa (T_f - T_a) - G_ab (T_a - T_b) - G_aa lap(T_a)

``lap`` is the 4-neighbour graph Laplacian (positive semi-definite; edges: only existing
neighbours), P the absorbed power per cell [W]. This is the simulator's network
(es_sim_plant.thermal) with the same parameter names and defaults (one definition:
es_physics.thermal_network.CellThermalParams); the estimator takes its
parameters separately, because a real mirror's are never known exactly. The base-plate
temperature T_b is not measured: the estimator carries it as a random-walk state (a Peltier
stage or thermal control may move it with no heat load).
Sensors see the actuator field at their positions through a first-order lag ``tau`` each
(one value for all, or one per sensor): the sensor temperatures are states of the model,

    tau_i dT_s,i/dt = (S T_a)_i - T_s,i

with ``S`` the sensors' bilinear view of the actuator field, and the readings measure T_s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace

import numpy as np
import numpy.typing as npt
from scipy import fft, sparse

from es_common.arrays import FloatArray, IndexArray
from es_physics.thermal_network import CellThermalParams
from es_thermal.errors import ThermalConfigError
from es_thermal.interpolation import sampling_matrix


@dataclass(frozen=True)
class NetworkParams(CellThermalParams):
    """Lumped thermal parameters of one actuator cell (uniform over the grid).

    Defaults: a 5 mm pitch grid behind a 4 mm glass face sheet with PMN-PT actuator columns
    (the simulator's defaults, one definition: es_physics.thermal_network).

    Attributes:
        face_capacitance: C_f, heat capacity of the face-sheet cell above one actuator [J/K].
        actuator_capacitance: C_a, heat capacity of one actuator column [J/K].
        face_to_actuator: G_fa, face-sheet cell to actuator conductance [W/K].
        actuator_to_base: G_ab, actuator to base-plate conductance [W/K].
        face_lateral: G_ff, conductance between neighbouring face-sheet cells [W/K].
        actuator_lateral: G_aa, conductance between neighbouring actuators [W/K].

    """

    def __post_init__(self) -> None:
        """Check the values.

        Raises:
            ThermalConfigError: a value out of range (the message names it).

        """
        for f in fields(self):
            value = getattr(self, f.name)
            if not np.isfinite(value) or value < 0.0:
                raise ThermalConfigError(
                    f"thermal parameter {f.name}={value} must be finite and >= 0"
                )
        for name in ("face_capacitance", "actuator_capacitance", "face_to_actuator"):
            if getattr(self, name) <= 0.0:
                raise ThermalConfigError(f"thermal parameter {name} must be > 0")

    def scaled(self, factor: float) -> NetworkParams:
        """Return every parameter multiplied by ``factor`` (a model deliberately off)."""
        return replace(self, **{f.name: getattr(self, f.name) * factor for f in fields(self)})

    def time_scaled(self, time_scale: float) -> NetworkParams:
        """Return a copy with capacitances (hence time constants) scaled by ``time_scale``.

        The simulator's scenarios shorten time this way.
        """
        return replace(
            self,
            face_capacitance=self.face_capacitance * time_scale,
            actuator_capacitance=self.actuator_capacitance * time_scale,
        )


def grid_laplacian(rows: int, cols: int) -> sparse.csr_matrix:
    """Return the 4-neighbour graph Laplacian of an R x C grid (positive semi-definite)."""

    def path(n: int) -> sparse.csr_matrix:
        if n == 1:
            return sparse.csr_matrix((1, 1))
        ones = np.ones(n - 1)
        adj = sparse.diags([ones, ones], [-1, 1], shape=(n, n))
        return sparse.csr_matrix(sparse.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj)

    lap = sparse.kron(path(rows), sparse.identity(cols)) + sparse.kron(
        sparse.identity(rows), path(cols)
    )
    return sparse.csr_matrix(lap)


@dataclass(frozen=True)
class StateLayout:
    """Where each group of states sits in the estimator's state vector."""

    cells: int
    sensors: int  # lag states; 0 when the sensors have no lag

    @property
    def face(self) -> slice:
        """Face-sheet temperatures."""
        return slice(0, self.cells)

    @property
    def actuator(self) -> slice:
        """Actuator temperatures."""
        return slice(self.cells, 2 * self.cells)

    @property
    def sensor(self) -> slice:
        """Lagged sensor temperatures."""
        return slice(2 * self.cells, 2 * self.cells + self.sensors)

    @property
    def base(self) -> int:
        """Index of the base-plate temperature."""
        return 2 * self.cells + self.sensors

    @property
    def size(self) -> int:
        """Number of states."""
        return 2 * self.cells + self.sensors + 1


#: A sensor without lag among lagging ones gets a lag state of this many sample periods: it
#: follows its site within a hundredth of a period, far below any sample's resolution.
NO_LAG_PERIODS = 0.01


def per_sensor(value: float | npt.ArrayLike, count: int, what: str) -> FloatArray:
    """Return ``value`` as one finite value per sensor (count,).

    ``value`` is one value for every sensor or a sequence of one per sensor.

    Raises:
        ThermalConfigError: a value that is not finite, or a sequence whose length is not
            ``count`` (the message names ``what``).

    """
    values = np.asarray(value, float)
    if values.ndim == 0:
        values = np.full(count, float(values))
    if values.shape != (count,):
        raise ThermalConfigError(
            f"{what}: one value or one per sensor ({count}), got shape {values.shape}"
        )
    if not np.all(np.isfinite(values)):
        raise ThermalConfigError(f"{what} must be finite, got {values.tolist()}")
    return values


def sensor_lags(sensor_tau: float | npt.ArrayLike, count: int) -> FloatArray:
    """Return the first-order lag of each of ``count`` sensors (count,) [s].

    ``sensor_tau`` is one value for every sensor or one per sensor.

    Raises:
        ThermalConfigError: a lag that is negative or not finite, or a per-sensor list whose
            length is not ``count``.

    """
    taus = per_sensor(sensor_tau, count, "sensor lag")
    if np.any(taus < 0.0):
        raise ThermalConfigError(f"sensor lags must be >= 0, got {taus.tolist()}")
    return taus


def lag_states(taus: FloatArray, sample_period: float) -> FloatArray | None:
    """Return the time constants of the sensors' lag states (S,) [s], None without lag.

    ``taus`` (S,) are the sensors' lags (:func:`sensor_lags`). No sensor lags: no lag
    states. Any lags: every sensor gets a state, a sensor without lag one of
    :data:`NO_LAG_PERIODS` sample periods.
    """
    if not np.any(taus > 0.0):
        return None
    return np.maximum(taus, NO_LAG_PERIODS * sample_period)


def continuous_model(
    params: NetworkParams,
    rows: int,
    cols: int,
    sampling: FloatArray,
    sensor_tau: float | FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, StateLayout]:
    """Return (A, B, H, layout) of dx/dt = A x + B P, y = H x in grid coordinates (dense).

    ``sampling`` (S x N) maps the actuator field to the sensors; ``sensor_tau`` [s] is their
    first-order lag, one for all or one per sensor (all 0: no lag states, the sensors see
    the actuators directly).

    Raises:
        ThermalConfigError: a lag out of range (:func:`sensor_lags`), or some sensors
            without lag among lagging ones (the estimator gives those a short lag of its
            sample period, :func:`lag_states`).

    """
    taus = sensor_lags(sensor_tau, sampling.shape[0])
    if np.any(taus > 0.0) and not np.all(taus > 0.0):
        raise ThermalConfigError("sensor lags: all > 0 or all 0 in the continuous model")
    A, B, H, layout = _assemble(
        params, grid_laplacian(rows, cols), np.ones(rows * cols),
        sparse.csr_matrix(sampling), taus if np.any(taus > 0.0) else None,
    )
    return A.toarray(), B.toarray(), H.toarray(), layout


def dct_matrix(n: int) -> FloatArray:
    """Return the orthonormal DCT-II matrix of size n (rows are the modes)."""
    k = np.arange(n)[:, None]
    i = np.arange(n)[None, :]
    c = np.sqrt(2.0 / n) * np.cos(np.pi * k * (2 * i + 1) / (2 * n))
    c[0] /= np.sqrt(2.0)
    return np.asarray(c, float)


#: Transforms of at most this many values are formed as a matrix (see :class:`GridTransform`).
DENSE_TRANSFORM_MAX = 256


@dataclass(frozen=True)
class GridTransform:
    """The orthonormal 2-D DCT-II ``T = kron(row, col)`` of a row-major field, or the identity.

    Make one with :meth:`dct` (an R x C grid) or :meth:`eye`.

    Applied by scipy's fast transform, never formed: O(N log N) per field instead of O(N^2),
    and no N x N matrix in memory at 64 x 64. Up to :data:`DENSE_TRANSFORM_MAX` values the
    matrix is formed once and applied as one product, which costs less than a small FFT.

    Attributes:
        row: R x R DCT matrix acting along the rows (:func:`dct_matrix`).
        col: C x C DCT matrix acting along the columns.
        identity: True when T is the identity (applied as a copy).

    """

    row: FloatArray
    col: FloatArray
    identity: bool = False
    dense: FloatArray | None = field(init=False, repr=False, compare=False, default=None)

    def __post_init__(self) -> None:
        if not self.identity and self.size <= DENSE_TRANSFORM_MAX:
            object.__setattr__(self, "dense", np.kron(self.row, self.col))

    @classmethod
    def dct(cls, rows: int, cols: int) -> GridTransform:
        """Return the 2-D DCT-II of an R x C grid; it diagonalises :func:`grid_laplacian`."""
        return cls(dct_matrix(rows), dct_matrix(cols))

    @classmethod
    def eye(cls, size: int) -> GridTransform:
        """Return the identity on ``size`` values."""
        return cls(np.eye(size), np.eye(1), identity=True)

    @property
    def size(self) -> int:
        """Number of values N = R C."""
        return self.row.shape[0] * self.col.shape[0]

    def forward(self, values: FloatArray) -> FloatArray:
        """Return ``T @ values`` for values of shape (N,) or (N, k)."""
        if self.dense is not None:
            return np.asarray(self.dense @ values, float)
        return self._fast(values, fft.dctn)

    def inverse(self, values: FloatArray) -> FloatArray:
        """Return ``T' @ values`` for values of shape (N,) or (N, k)."""
        if self.dense is not None:
            return np.asarray(self.dense.T @ values, float)
        return self._fast(values, fft.idctn)

    def columns(self, index: IndexArray) -> FloatArray:
        """Return the columns ``T[:, index]`` as a dense (N, len(index)) array."""
        r, c = np.divmod(index, self.col.shape[0])
        out = self.row[:, r][:, None, :] * self.col[:, c][None, :, :]
        return np.asarray(out.reshape(self.size, index.size), float)

    def _fast(self, values: FloatArray, transform: Callable[..., FloatArray]) -> FloatArray:
        x = np.asarray(values, float)
        if self.identity:
            return x.copy()
        grid = x.reshape(self.row.shape[0], self.col.shape[0], -1)
        out = transform(grid, type=2, norm="ortho", axes=(0, 1), workers=1)
        return np.asarray(out, float).reshape(x.shape)


def laplacian_eigenvalues(rows: int, cols: int) -> FloatArray:
    """Return the eigenvalues of :func:`grid_laplacian` in :meth:`GridTransform.dct` order (N,)."""
    lam_r = 2.0 - 2.0 * np.cos(np.pi * np.arange(rows) / rows)
    lam_c = 2.0 - 2.0 * np.cos(np.pi * np.arange(cols) / cols)
    return np.asarray((lam_r[:, None] + lam_c[None, :]).ravel(), float)


def _regular_axes(positions: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """Return (row positions, column positions) of a full regular grid listed row-major."""
    rows_at = np.unique(positions[:, 0])
    cols_at = np.unique(positions[:, 1])
    if rows_at.size * cols_at.size != positions.shape[0]:
        return None
    r, c = np.meshgrid(rows_at, cols_at, indexing="ij")
    if not np.array_equal(np.column_stack([r.ravel(), c.ravel()]), positions):
        return None
    return rows_at, cols_at


def sensor_transform(positions: FloatArray) -> GridTransform:
    """Return an orthonormal transform of the sensor vector that keeps modes apart.

    Sensors on a full regular grid, listed row-major (one per actuator, or one per block),
    get the 2-D DCT of that grid: sensor modes then see only a few actuator modes each.
    Any other layout gets the identity.
    """
    axes = _regular_axes(positions)
    if axes is None:
        return GridTransform.eye(positions.shape[0])
    return GridTransform.dct(axes[0].size, axes[1].size)


def modal_sampling(
    rows: int, cols: int, positions: FloatArray, sensors: GridTransform
) -> sparse.csr_matrix:
    """Return the sensors' view of the actuator field in modes, ``Ts S D'`` (S x N, sparse).

    ``S`` is the bilinear sampling (:func:`es_thermal.interpolation.sampling_matrix`), ``D``
    the grid DCT and ``Ts`` the sensor transform. On a regular sensor grid the bilinear map
    is a Kronecker product of one-dimensional ones, and so is its modal form: no S x N dense
    product. Entries at round-off level (relative 1e-12) are dropped: they are not coupling.
    """
    grid = GridTransform.dct(rows, cols)
    axes = _regular_axes(positions)
    if axes is None or sensors.identity:
        dense = grid.forward(sampling_matrix(rows, cols, positions).T).T
        return sparse.csr_matrix(_drop_roundoff(sensors.forward(dense)))
    factors = []
    for n, at, own, theirs in (
        (rows, axes[0], grid.row, sensors.row), (cols, axes[1], grid.col, sensors.col)
    ):
        weights = sampling_matrix(n, 1, np.column_stack([at, np.zeros_like(at)]))
        factors.append(sparse.csr_matrix(_drop_roundoff(theirs @ weights @ own.T)))
    return sparse.csr_matrix(sparse.kron(factors[0], factors[1]))


def _drop_roundoff(matrix: FloatArray) -> FloatArray:
    """Return ``matrix`` with entries below 1e-12 of its largest set to zero (in place)."""
    matrix[np.abs(matrix) < 1e-12 * np.max(np.abs(matrix))] = 0.0
    return matrix


def modal_model(
    params: NetworkParams,
    rows: int,
    cols: int,
    positions: FloatArray,
    lags: FloatArray | None,
    *,
    sensors: GridTransform,
) -> tuple[sparse.csr_matrix, sparse.csr_matrix, sparse.csr_matrix, StateLayout]:
    """Return :func:`continuous_model` in modal coordinates, as sparse matrices.

    ``lags`` are the time constants of the sensors' lag states (S,) [s] (:func:`lag_states`;
    None: no lag states). Face and actuator fields are expressed in grid DCT modes
    (:meth:`GridTransform.dct`), lag states and measurements through the sensor transform
    ``sensors``; lags that differ between sensors need the identity there (the lag is
    diagonal only in sensor coordinates, or when it is one value). The network is then
    block diagonal: mode k of the face sheet couples only to mode k of the actuators, the
    base plate only to mode 0, and a sensor mode only to the few actuator modes that alias
    onto it. The input is the heat load in modes as well.
    """
    lam = sparse.diags(laplacian_eigenvalues(rows, cols))
    uniform = np.zeros(rows * cols)
    uniform[0] = np.sqrt(rows * cols)  # a uniform field is all mode 0 (exactly, not ~1e-16)
    sampled = modal_sampling(rows, cols, positions, sensors)
    if lags is not None and not sensors.identity and np.ptp(lags) > 0.0:
        raise ThermalConfigError("sensor lags that differ need the identity sensor transform")
    return _assemble(params, lam, uniform, sampled, lags)


def _assemble(
    params: NetworkParams,
    lap: sparse.spmatrix,
    base_coupling: FloatArray,
    sampling: sparse.spmatrix,
    lags: FloatArray | None,
) -> tuple[sparse.csr_matrix, sparse.csr_matrix, sparse.csr_matrix, StateLayout]:
    """Build sparse (A, B, H, layout) in any orthonormal basis of the grid.

    ``lap`` is the Laplacian, ``base_coupling`` a uniform unit field and ``sampling`` the
    sensors' view of the actuator field, all in that basis; ``lags`` the lag states' time
    constants (S,), diagonal in the sensors' basis (None: no lag states).
    """
    cells = lap.shape[0]
    count = sampling.shape[0]
    layout = StateLayout(cells, 0 if lags is None else count)
    eye = sparse.identity(cells, format="csr")
    p = params
    base = sparse.csr_matrix(base_coupling[:, None])
    face_face = -(p.face_to_actuator * eye + p.face_lateral * lap) / p.face_capacitance
    act_act = -(
        (p.face_to_actuator + p.actuator_to_base) * eye + p.actuator_lateral * lap
    ) / p.actuator_capacitance
    blocks: list[list[sparse.spmatrix | None]] = [
        [face_face, p.face_to_actuator * eye / p.face_capacitance, None, None],
        [p.face_to_actuator * eye / p.actuator_capacitance, act_act, None,
         base * p.actuator_to_base / p.actuator_capacitance],
    ]
    lag_eye = sparse.identity(count, format="csr")
    if lags is not None:
        rate = sparse.diags(1.0 / lags, format="csr")
        blocks.append([None, rate @ sampling, -rate, None])
    blocks.append([None, None, None, sparse.csr_matrix((1, 1))])
    if not layout.sensors:
        blocks = [[b for j, b in enumerate(row) if j != 2] for row in blocks]
    A = sparse.csr_matrix(sparse.bmat(blocks, format="csr"))
    B = sparse.vstack(
        [eye / p.face_capacitance, sparse.csr_matrix((layout.size - cells, cells))], format="csr"
    )
    if layout.sensors:
        H = sparse.hstack(
            [sparse.csr_matrix((count, 2 * cells)), lag_eye, sparse.csr_matrix((count, 1))],
            format="csr",
        )
    else:
        H = sparse.hstack(
            [sparse.csr_matrix((count, cells)), sampling, sparse.csr_matrix((count, 1))],
            format="csr",
        )
    return A, sparse.csr_matrix(B), sparse.csr_matrix(H), layout
