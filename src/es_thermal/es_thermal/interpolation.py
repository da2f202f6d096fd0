"""Sensor positions on the actuator grid and the linear maps between sensors and actuators.

Actuator (r, c) sits at grid coordinates (row=r, col=c). A sensor sits at a fractional
(row, col) position; when there are as many sensors as actuators and no positions are given,
sensor i sits on actuator i (row-major), as the interface contract says.

Two maps, both precomputed so that applying them is one matrix product:

- :func:`sampling_matrix` (S x N): what a sensor at its position sees of the actuator
  temperature field (bilinear interpolation between the four surrounding actuators). The
  model-based estimator uses it as its measurement model.
- :func:`interpolation_matrix` (N x S, sparse): actuator temperatures from sensor values
  (linear interpolation on a Delaunay triangulation of the sensors, nearest sensor outside
  their convex hull). The low-pass estimator uses it, the model estimator to start from.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import sparse
from scipy.spatial import Delaunay, QhullError, cKDTree

from es_common.arrays import BoolArray, FloatArray
from es_thermal.errors import ThermalConfigError, ThermalInputError


def actuator_positions(rows: int, cols: int) -> FloatArray:
    """Return the (row, col) coordinates of every actuator, row-major, shape (R*C, 2)."""
    r, c = np.meshgrid(np.arange(rows, dtype=float), np.arange(cols, dtype=float), indexing="ij")
    return np.column_stack([r.ravel(), c.ravel()])


def block_centre_positions(rows: int, cols: int, pitch: int) -> FloatArray:
    """Return one sensor position per ``pitch`` x ``pitch`` block of actuators, at its centre.

    Blocks cut by the grid edge get their sensor at the centre of the actuators they hold.
    ``pitch == 1`` puts one sensor on every actuator (the contract's S == R*C case).

    Raises:
        ThermalConfigError: a value out of range (the message names it).

    """
    if pitch < 1:
        raise ThermalConfigError(f"sensor pitch must be >= 1, got {pitch}")

    def centres(n: int) -> FloatArray:
        starts = np.arange(0, n, pitch, dtype=float)
        ends = np.minimum(starts + pitch, n) - 1.0
        return np.asarray(0.5 * (starts + ends), dtype=float)

    r, c = np.meshgrid(centres(rows), centres(cols), indexing="ij")
    return np.column_stack([r.ravel(), c.ravel()])


def sensor_positions(
    rows: int, cols: int, sensor_rows: Sequence[float], sensor_cols: Sequence[float]
) -> FloatArray:
    """Return validated sensor positions, shape (S, 2).

    Empty ``sensor_rows`` and ``sensor_cols`` mean one sensor on every actuator.

    Raises:
        ThermalConfigError: the two lists differ in length, hold a non-finite value or a position
            outside the grid ([0, R-1] x [0, C-1]).

    """
    if len(sensor_rows) != len(sensor_cols):
        raise ThermalConfigError(
            f"sensor_rows has {len(sensor_rows)} entries, sensor_cols {len(sensor_cols)}"
        )
    if len(sensor_rows) == 0:
        return actuator_positions(rows, cols)
    pos = np.column_stack([np.asarray(sensor_rows, float), np.asarray(sensor_cols, float)])
    if not np.all(np.isfinite(pos)):
        raise ThermalConfigError("sensor positions must be finite")
    outside = (pos[:, 0] < 0) | (pos[:, 0] > rows - 1) | (pos[:, 1] < 0) | (pos[:, 1] > cols - 1)
    if np.any(outside):
        first = int(np.flatnonzero(outside)[0])
        raise ThermalConfigError(
            f"sensor {first} at ({pos[first, 0]}, {pos[first, 1]}) lies outside the "
            f"{rows} x {cols} grid [0, {rows - 1}] x [0, {cols - 1}]"
        )
    return pos


def sampling_matrix(rows: int, cols: int, positions: FloatArray) -> FloatArray:
    """Return the S x N bilinear map from the actuator temperature grid to the sensors."""
    return np.asarray(sparse_sampling(rows, cols, positions).toarray(), float)


def sparse_sampling(rows: int, cols: int, positions: FloatArray) -> sparse.csr_matrix:
    """Return :func:`sampling_matrix` as a sparse matrix (at most four entries a row)."""
    count = positions.shape[0]
    r0 = np.clip(np.floor(positions[:, 0]).astype(int), 0, max(rows - 2, 0))
    c0 = np.clip(np.floor(positions[:, 1]).astype(int), 0, max(cols - 2, 0))
    fr = positions[:, 0] - r0
    fc = positions[:, 1] - c0
    r1 = np.minimum(r0 + 1, rows - 1)
    c1 = np.minimum(c0 + 1, cols - 1)
    idx = np.tile(np.arange(count), 4)
    column = np.concatenate([r0 * cols + c0, r0 * cols + c1, r1 * cols + c0, r1 * cols + c1])
    weight = np.concatenate([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc])
    # Duplicates are summed: on a one-row or one-column grid r1 == r0 (or c1 == c0).
    return sparse.csr_matrix((weight, (idx, column)), shape=(count, rows * cols))


def interpolation_matrix(
    rows: int, cols: int, positions: FloatArray, valid: BoolArray | None = None
) -> sparse.csr_matrix:
    """Return the N x S map from sensor values to actuator temperatures (sparse).

    Only sensors with ``valid`` true get weight (their columns are zero otherwise). Inside
    the convex hull of the valid sensors the map interpolates linearly (barycentric weights
    on the Delaunay triangulation: at most three entries a row), outside it takes the
    nearest valid sensor; with fewer than three valid sensors, or all of them on one line,
    nearest-sensor everywhere.

    Raises:
        ThermalInputError: no sensor is valid.

    """
    count = positions.shape[0]
    use = np.ones(count, bool) if valid is None else np.asarray(valid, bool)
    chosen = np.flatnonzero(use)
    if chosen.size == 0:
        raise ThermalInputError("no valid sensor to interpolate from")
    targets = actuator_positions(rows, cols)
    pts = positions[chosen]
    simplex = np.full(targets.shape[0], -1)
    if chosen.size >= 3:
        try:
            tri = Delaunay(pts)
            simplex = np.asarray(tri.find_simplex(targets), int)
        except QhullError:  # collinear or coincident sensors: no triangulation
            pass
    inside = np.flatnonzero(simplex >= 0)
    outside = np.flatnonzero(simplex < 0)
    row_parts = [np.repeat(inside, 3)]
    col_parts = []
    weight_parts = []
    if inside.size:
        transform = tri.transform[simplex[inside]]
        partial = np.einsum("tij,tj->ti", transform[:, :2], targets[inside] - transform[:, 2])
        weight_parts.append(np.column_stack([partial, 1.0 - partial.sum(axis=1)]).ravel())
        col_parts.append(chosen[tri.simplices[simplex[inside]]].ravel())
    if outside.size:
        _, nearest = cKDTree(pts).query(targets[outside])
        row_parts.append(outside)
        col_parts.append(chosen[nearest])
        weight_parts.append(np.ones(outside.size))
    weights = np.concatenate(weight_parts)
    return sparse.csr_matrix(
        (weights, (np.concatenate(row_parts), np.concatenate(col_parts))),
        shape=(targets.shape[0], count),
    )
