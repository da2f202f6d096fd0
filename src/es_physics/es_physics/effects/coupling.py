"""Neighbour coupling through the mirror's face sheet.

z = z_free + c lap(z_free), lap the 4-neighbour graph Laplacian whose edges use only existing
neighbours (the face sheet ends at the grid border). Feedforward: (I + c lap) z_free = z_ref
solved for z_free (``compensation.coupling``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
from scipy.sparse import csc_matrix, diags, identity
from scipy.sparse.linalg import splu

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role
from es_physics.effects.stages import Compensator, PlantContext, PlantStage, StepState


def grid_laplacian(z: FloatArray) -> FloatArray:
    """Return the 4-neighbour Laplacian sum(neighbours) - n_neighbours z over the last two axes."""
    lap = np.zeros_like(z)
    lap[..., 1:, :] += z[..., :-1, :] - z[..., 1:, :]
    lap[..., :-1, :] += z[..., 1:, :] - z[..., :-1, :]
    lap[..., :, 1:] += z[..., :, :-1] - z[..., :, 1:]
    lap[..., :, :-1] += z[..., :, 1:] - z[..., :, :-1]
    return lap


def neighbour_laplacian(values: FloatArray, grid: tuple[int, int]) -> FloatArray:
    """Return the 4-neighbour Laplacian sum_j (x_j - x_i) of (A, n) values on a row-major grid."""
    rows, cols = grid
    x = values.reshape(rows, cols, -1)
    total = np.zeros_like(x)
    count = np.zeros((rows, cols, 1))
    total[1:] += x[:-1]
    total[:-1] += x[1:]
    total[:, 1:] += x[:, :-1]
    total[:, :-1] += x[:, 1:]
    count[1:] += 1.0
    count[:-1] += 1.0
    count[:, 1:] += 1.0
    count[:, :-1] += 1.0
    return np.asarray((total - count * x).reshape(values.shape), np.float64)


def neighbour_count(grid: tuple[int, int]) -> FloatArray:
    """Return the number of existing 4-neighbours of each actuator, shape (A, 1)."""
    rows, cols = grid
    ones = np.ones((rows * cols, 1))
    return -neighbour_laplacian(ones, grid)


class CouplingStage(PlantStage):
    """z = z_free + c lap(z_free) over the grid."""

    def __init__(self, coefficient: float) -> None:
        self.coefficient = coefficient

    def displacement(self, z: FloatArray, step: StepState) -> FloatArray:
        """Return z + c lap(z)."""
        return np.asarray(z + self.coefficient * grid_laplacian(z), np.float64)


def laplacian(shape: tuple[int, int]) -> csc_matrix:
    """Return the 4-neighbour Laplacian of a row-major grid (edges: existing neighbours only)."""
    rows, cols = shape
    size = rows * cols
    index = np.arange(size).reshape(shape)
    pairs = [
        (index[:, :-1].ravel(), index[:, 1:].ravel()),
        (index[:-1, :].ravel(), index[1:, :].ravel()),
    ]
    i = np.concatenate([p[0] for p in pairs] + [p[1] for p in pairs])
    j = np.concatenate([p[1] for p in pairs] + [p[0] for p in pairs])
    adjacency = csc_matrix((np.ones(i.size), (i, j)), shape=(size, size))
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    return csc_matrix(adjacency - diags(degree))


class CouplingInverse(Compensator):
    """Solve (I + c lap) z_free = z_ref for a grid; the LU factorisation is done once."""

    def __init__(self, coefficient: float, shape: tuple[int, int]) -> None:
        self.coefficient = coefficient
        self.shape = shape
        self._lu = (
            splu(csc_matrix(identity(shape[0] * shape[1]) + coefficient * laplacian(shape)))
            if coefficient != 0.0
            else None
        )

    def __call__(self, z_ref: FloatArray) -> FloatArray:
        """Return z_free [m] for the set points ``z_ref`` (grid of ``shape``)."""
        if self._lu is None:
            return z_ref
        return np.asarray(self._lu.solve(z_ref.ravel()).reshape(self.shape), np.float64)

    def setpoint(self, z: FloatArray, T: FloatArray, t: float) -> FloatArray:
        """Return the free displacements (see :meth:`__call__`)."""
        return self(z)


class Coupling(Effect):
    """Face-sheet coupling of neighbouring actuators."""

    name: ClassVar[str] = "coupling"
    summary: ClassVar[str] = "neighbouring actuators pull on each other through the face sheet"
    role: ClassVar[Role] = Role.SPATIAL
    simulated: ClassVar[bool] = True
    plant: ClassVar[tuple[Parameter, ...]] = (
        # I + c lap stays invertible for c < 1/8 (lap's eigenvalues lie in [-8, 0])
        Parameter("coefficient", "", 0.0, 0.125, 0.05, "Laplacian coefficient c", high_open=True),
    )
    fit_parameters: ClassVar[tuple[str, ...]] = ("coefficient",)
    compensation: ClassVar[tuple[Parameter, ...]] = (
        Parameter("coupling", "", -0.12, 0.12, 0.0, "Laplacian coefficient c (0 = off)"),
    )

    def reported(self, fit: FittedEffect) -> dict[str, float]:
        """Return ``coefficient``."""
        return {"coefficient": float(fit.values["coefficient"])}

    def problem(self, reported: dict[str, float]) -> str | None:
        """Reject a coefficient <= 0 (a face sheet pulls neighbours together)."""
        if reported["coefficient"] <= 0:
            return f"coefficient {reported['coefficient']:.3g} is not positive"
        return None

    def compensation_values(
        self, reported: dict[str, float], start_time: float
    ) -> dict[str, float]:
        """Solve the coupling for the free displacements."""
        return {"coupling": reported["coefficient"]}

    def plant_stage(self, settings: Mapping[str, float], context: PlantContext) -> PlantStage:
        """Return the face sheet's spreading."""
        return CouplingStage(settings["coefficient"])

    def compensator(
        self,
        values: Mapping[str, float],
        shape: tuple[int, int],
        previous: Compensator | None = None,
        last_voltage: FloatArray | None = None,
    ) -> Compensator | None:
        """Return the coupling solver, or None when ``coupling`` is 0."""
        if values["coupling"] == 0.0:
            return None
        return CouplingInverse(values["coupling"], shape)
