"""Neighbour coupling through the mirror's face sheet.

z = z_free + c lap(z_free), lap the 4-neighbour graph Laplacian whose edges use only existing
neighbours (the face sheet ends at the grid border). Feedforward: (I + c lap) z_free = z_ref
solved for z_free (``compensation.coupling``).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from es_physics.effects.base import Effect, FittedEffect, FloatArray, Parameter, Role


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
