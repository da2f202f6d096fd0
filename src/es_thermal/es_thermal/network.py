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

    Defaults: a 5 mm pitch grid behind a 2 mm glass face sheet with PMN-PT actuator columns
    (the simulator's defaults; their derivation is in es_sim_plant.thermal).

    Attributes:
        face_capacitance: C_f, heat capacity of the face-sheet cell above one actuator [J/K].
        actuator_capacitance: C_a, heat capacity of one actuator column [J/K].
        face_to_actuator: G_fa, face-sheet cell to actuator conductance [W/K].
        actuator_to_base: G_ab, actuator to base-plate conductance [W/K].
        face_lateral: G_ff, conductance between neighbouring face-sheet cells [W/K].
        actuator_lateral: G_aa, conductance between neighbouring actuators [W/K].

    """

    face_capacitance: float = 0.082
    actuator_capacitance: float = 0.117
    face_to_actuator: float = 5.4e-3
    actuator_to_base: float = 5.4e-3
    face_lateral: float = 2.6e-3
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
    """Return (A, B, H, layout) of dx/dt = A x + B P, y = H x.

    ``sampling`` (S x N) maps the actuator field to the sensors; ``sensor_tau`` [s] is their
    first-order lag (0: no lag states, the sensors see the actuators directly).
    """
    cells = rows * cols
    count = sampling.shape[0]
    layout = StateLayout(cells, count if sensor_tau > 0.0 else 0)
    lap = grid_laplacian(rows, cols).toarray()
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
    A[a, b] = p.actuator_to_base / p.actuator_capacitance
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
