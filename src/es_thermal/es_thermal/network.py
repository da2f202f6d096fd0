"""Thermal network of the mirror as the model-based estimator sees it.

Per actuator cell two nodes, the mirror face sheet above the actuator (it absorbs the UV
heat load) and the actuator itself, plus one base plate shared by all cells:

    C_f dT_f/dt = P - G_fa (T_f - T_a) - G_ff lap(T_f)
    C_a dT_a/dt = G_fa (T_f - T_a) - G_ab (T_a - T_b) - G_aa lap(T_a)

``lap`` is the 4-neighbour graph Laplacian (positive semi-definite; edges: only existing
neighbours), P the absorbed power per cell [W]. This is the simulator's network
(es_sim_plant.thermal) with the same parameter names and defaults; the estimator takes its
parameters separately, because a real mirror's are never known exactly. The base-plate
temperature T_b is not measured: the estimator carries it as a random-walk state (a Peltier
stage or thermal control may move it with no heat load).
Sensors see the actuator field at their positions through a first-order lag ``tau``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
import numpy.typing as npt
from scipy import sparse

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class NetworkParams:
    """Lumped thermal parameters of one actuator cell (uniform over the grid).

    Defaults: a 5 mm pitch grid behind a 4 mm glass face sheet with PMN-PT actuator columns
    (the simulator's defaults; their derivation is in es_sim_plant.thermal).

    Attributes:
        face_capacitance: C_f, heat capacity of the face-sheet cell above one actuator [J/K].
        actuator_capacitance: C_a, heat capacity of one actuator column [J/K].
        face_to_actuator: G_fa, face-sheet cell to actuator conductance [W/K].
        actuator_to_base: G_ab, actuator to base-plate conductance [W/K].
        face_lateral: G_ff, conductance between neighbouring face-sheet cells [W/K].
        actuator_lateral: G_aa, conductance between neighbouring actuators [W/K].

    """

    face_capacitance: float = 0.163
    actuator_capacitance: float = 0.187
    face_to_actuator: float = 3.4e-3
    actuator_to_base: float = 3.4e-3
    face_lateral: float = 5.2e-3
    actuator_lateral: float = 0.2e-3

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not np.isfinite(value) or value < 0.0:
                raise ValueError(f"thermal parameter {f.name}={value} must be finite and >= 0")
        for name in ("face_capacitance", "actuator_capacitance", "face_to_actuator"):
            if getattr(self, name) <= 0.0:
                raise ValueError(f"thermal parameter {name} must be > 0")

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


def continuous_model(
    params: NetworkParams,
    rows: int,
    cols: int,
    sampling: FloatArray,
    sensor_tau: float,
) -> tuple[FloatArray, FloatArray, FloatArray, StateLayout]:
    """Return (A, B, H, layout) of dx/dt = A x + B P, y = H x in grid coordinates.

    ``sampling`` (S x N) maps the actuator field to the sensors; ``sensor_tau`` [s] is their
    first-order lag (0: no lag states, the sensors see the actuators directly).
    """
    lap = grid_laplacian(rows, cols).toarray()
    return _assemble(params, lap, np.ones(rows * cols), sampling, sensor_tau)


def dct_matrix(n: int) -> FloatArray:
    """Return the orthonormal DCT-II matrix of size n (rows are the modes)."""
    k = np.arange(n)[:, None]
    i = np.arange(n)[None, :]
    c = np.sqrt(2.0 / n) * np.cos(np.pi * k * (2 * i + 1) / (2 * n))
    c[0] /= np.sqrt(2.0)
    return np.asarray(c, float)


def grid_dct(rows: int, cols: int) -> FloatArray:
    """Return the orthonormal 2-D DCT-II of a row-major R x C grid as an N x N matrix.

    It diagonalises :func:`grid_laplacian`: ``D L D' = diag(laplacian_eigenvalues)``.
    """
    return np.asarray(np.kron(dct_matrix(rows), dct_matrix(cols)), float)


def laplacian_eigenvalues(rows: int, cols: int) -> FloatArray:
    """Return the eigenvalues of :func:`grid_laplacian` in :func:`grid_dct` mode order (N,)."""
    lam_r = 2.0 - 2.0 * np.cos(np.pi * np.arange(rows) / rows)
    lam_c = 2.0 - 2.0 * np.cos(np.pi * np.arange(cols) / cols)
    return np.asarray((lam_r[:, None] + lam_c[None, :]).ravel(), float)


def sensor_transform(positions: FloatArray) -> FloatArray:
    """Return an orthonormal S x S transform of the sensor vector that keeps modes apart.

    Sensors on a full regular grid, listed row-major (one per actuator, or one per block),
    get the 2-D DCT of that grid: sensor modes then see only a few actuator modes each.
    Any other layout gets the identity.
    """
    rows_at = np.unique(positions[:, 0])
    cols_at = np.unique(positions[:, 1])
    if rows_at.size * cols_at.size == positions.shape[0]:
        r, c = np.meshgrid(rows_at, cols_at, indexing="ij")
        if np.array_equal(np.column_stack([r.ravel(), c.ravel()]), positions):
            return grid_dct(rows_at.size, cols_at.size)
    return np.eye(positions.shape[0])


def modal_model(
    params: NetworkParams,
    rows: int,
    cols: int,
    sampling: FloatArray,
    sensor_tau: float,
    *,
    sensors: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, StateLayout]:
    """Return :func:`continuous_model` in modal coordinates.

    Face and actuator fields are expressed in grid DCT modes (``grid_dct``), lag states and
    measurements through the sensor transform ``sensors`` (S x S, orthonormal). The network
    is then block diagonal: mode k of the face sheet couples only to mode k of the actuators,
    the base plate only to mode 0, and a sensor mode only to the few actuator modes that
    alias onto it. The input is the heat load in modes as well.
    """
    dct = grid_dct(rows, cols)
    lam = np.diag(laplacian_eigenvalues(rows, cols))
    uniform = np.zeros(rows * cols)
    uniform[0] = np.sqrt(rows * cols)  # a uniform field is all mode 0 (exactly, not ~1e-16)
    sampled = sensors @ sampling @ dct.T
    sampled[np.abs(sampled) < 1e-12 * np.max(np.abs(sampled))] = 0.0  # round-off, not coupling
    return _assemble(params, lam, uniform, sampled, sensor_tau)


def _assemble(
    params: NetworkParams,
    lap: FloatArray,
    base_coupling: FloatArray,
    sampling: FloatArray,
    sensor_tau: float,
) -> tuple[FloatArray, FloatArray, FloatArray, StateLayout]:
    """Build (A, B, H, layout) in any orthonormal basis of the grid.

    ``lap`` is the Laplacian, ``base_coupling`` a uniform unit field and ``sampling`` the
    sensors' view of the actuator field, all in that basis.
    """
    cells = lap.shape[0]
    count = sampling.shape[0]
    layout = StateLayout(cells, count if sensor_tau > 0.0 else 0)
    eye = np.eye(cells)
    p = params
    A = np.zeros((layout.size, layout.size))
    m, a, b = layout.face, layout.actuator, layout.base
    A[m, m] = -(p.face_to_actuator * eye + p.face_lateral * lap) / p.face_capacitance
    A[m, a] = p.face_to_actuator * eye / p.face_capacitance
    A[a, m] = p.face_to_actuator * eye / p.actuator_capacitance
    A[a, a] = -(
        (p.face_to_actuator + p.actuator_to_base) * eye + p.actuator_lateral * lap
    ) / p.actuator_capacitance
    A[a, b] = base_coupling * p.actuator_to_base / p.actuator_capacitance
    B = np.zeros((layout.size, cells))
    B[m, :] = eye / p.face_capacitance
    H = np.zeros((count, layout.size))
    if layout.sensors:
        s = layout.sensor
        A[s, a] = sampling / sensor_tau
        A[s, s] = -np.eye(count) / sensor_tau
        H[:, s] = np.eye(count)
    else:
        H[:, a] = sampling
    return A, B, H, layout
