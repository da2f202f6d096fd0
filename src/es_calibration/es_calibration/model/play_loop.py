"""The play operator's recursion over time, compiled (numba).

The play operator is a recursion over time, y_i = min(max(y_(i-1), V_i - r), V_i + r): in
numpy each time step is four calls over the actuators, about 8 us per step on a small
grid, so a 1 x 1 recording of 23 s at 5 kHz took about 0.9 s per operator, and the effect
search evaluates dozens (most of a hysteresis case's time). Here the whole recursion is one
compiled loop. It does the same IEEE operations as :func:`es_calibration.model.composite.
play_operator`'s numpy loop (a subtraction, a maximum, an addition, a minimum per element and
step; NaN propagates as in ``np.maximum``/``np.minimum``), so both give the same numbers.

Imported only where the kernels are ``fused`` (:func:`es_feedforward.kernels.default_backend`):
importing this module imports numba and loads the loop from numba's cache (compiled on the
first use on a machine). A module-level function, so that the cache is found by every new
process.
"""

from __future__ import annotations

import math

import numba

from es_common.arrays import FloatArray, IndexArray


@numba.njit(cache=True, nogil=True)
def play_rows(  # noqa: PLR0917 (numba calls are positional)
    command: FloatArray,
    columns: IndexArray,
    threshold: FloatArray,
    state: FloatArray,
    keep: IndexArray,
    out: FloatArray,
) -> None:
    """Run the play operator over ``command`` (N, C) up to the last row of ``keep``.

    Element j of the state (M,) reads command column ``columns[j]`` with threshold
    ``threshold[j]``; ``state`` is updated in place; row k of ``out`` (len(keep), M) gets the
    state after command row ``keep[k]`` (``keep`` sorted, non-negative, repeats allowed).
    """
    n_keep = keep.shape[0]
    slot = 0
    while slot < n_keep and keep[slot] < 0:  # no such row: left as it is, as numpy's loop does
        slot += 1
    if slot == n_keep:
        return
    for i in range(keep[n_keep - 1] + 1):
        for j in range(state.shape[0]):
            value = command[i, columns[j]]
            current = state[j]
            low = value - threshold[j]
            if low > current or math.isnan(low):  # np.maximum: the larger, NaN if either is
                current = low
            high = value + threshold[j]
            if high < current or math.isnan(high):  # np.minimum
                current = high
            state[j] = current
        while slot < n_keep and keep[slot] == i:
            out[slot, :] = state
            slot += 1
