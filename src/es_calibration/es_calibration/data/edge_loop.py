"""The command edges' departures and their test against the neighbourhood, compiled (numba).

:func:`es_calibration.data.edges.departures` and the two windowed maxima of the edge rule
make several full passes over the command (N, A) in numpy: on a 64 x 64 grid of 5 minutes
at 500 Hz, where the grid-wide refit looks for every actuator's own edges
(:class:`~es_calibration.data.edges.EdgeStream`), about 56 s of CPU. Here one pass writes
the departures and a second tests only the intervals whose departure exceeds the floor
(almost none on a smooth drive), reading their neighbourhoods then. Same IEEE operations in
the same order as the numpy path, so both find the same pairs (tests/es_calibration/
test_edges.py).

Imported only where the kernels are ``fused`` (:func:`es_feedforward.kernels.default_backend`),
as :mod:`es_calibration.model.lowpass_loop`.
"""

from __future__ import annotations

import numba
import numpy as np

from es_common.arrays import BoolArray, FloatArray, IndexArray


@numba.njit(cache=True, nogil=True)
def departure_rows(  # noqa: PLR0917 (numba calls are positional)
    command: FloatArray, first_column: int, length: FloatArray, weight: FloatArray,
    usable: BoolArray, period: float, out: FloatArray,
) -> None:
    """Write the intervals' departures of columns ``first_column`` on into ``out``.

    As edges.departures: ``command`` (Nc, >= first_column + C) [V], ``out`` (Nc - 1, C),
    ``length`` (Nc - 1,) the intervals' lengths (1 where not regular), ``weight`` and
    ``usable`` (Nc - 3,) each middle interval's interpolation weight and whether the three
    intervals around it are regular. Each slope is computed once (the same quotient the
    numpy path computes for each of its three uses).
    """
    n, columns = out.shape
    for j in range(n):
        for c in range(columns):
            out[j, c] = 0.0
    if n < 3:
        return
    before = np.empty(columns)
    here = np.empty(columns)
    after = np.empty(columns)
    for c in range(columns):
        k = first_column + c
        before[c] = (command[1, k] - command[0, k]) / length[0]
        here[c] = (command[2, k] - command[1, k]) / length[1]
    for j in range(1, n - 1):
        step = length[j + 1]
        for c in range(columns):  # whole rows: the loops vectorise
            after[c] = (command[j + 2, first_column + c] - command[j + 1, first_column + c]) / step
        if usable[j - 1]:
            w = weight[j - 1]
            for c in range(columns):
                out[j, c] = np.abs(here[c] - (before[c] + (after[c] - before[c]) * w)) * period
        before, here, after = here, after, before


@numba.njit(cache=True, nogil=True)
def edge_hits(  # noqa: PLR0917 (numba calls are positional)
    dep: FloatArray, first: int, stop: int, floor: float, ratio: float, window: int,
    intervals: IndexArray, columns: IndexArray,
) -> int:
    """Find the edges among the intervals [first, stop); return how many there are.

    An edge: the departure exceeds ``floor`` and ``ratio`` times the smaller of the largest
    departures of the ``window`` - 1 intervals ending two before it and of those starting
    two after it (a side reaching past either end of ``dep`` does not count). The first
    ``len(intervals)`` edges are written to ``intervals`` and ``columns``, in row-major order
    (call again with room for all when the count is larger).
    """
    n, width = dep.shape
    found = 0
    room = intervals.shape[0]
    for i in range(first, stop):
        for c in range(width):
            d = dep[i, c]
            if not d > floor:
                continue
            before = np.inf
            if i - window >= 0:
                before = dep[i - window, c]
                for k in range(i - window + 1, i - 1):
                    before = max(before, dep[k, c])
            after = np.inf
            if i + window <= n - 1:
                after = dep[i + 2, c]
                for k in range(i + 3, i + window + 1):
                    after = max(after, dep[k, c])
            if d > ratio * min(before, after):
                if found < room:
                    intervals[found] = i
                    columns[found] = c
                found += 1
    return found
