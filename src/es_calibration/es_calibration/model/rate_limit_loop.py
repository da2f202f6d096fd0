"""The slew-rate limiter over a whole record, compiled (numba).

:func:`es_physics.effects.discovered.rate_limited` steps through the samples in Python
(a few microseconds per sample): a 5-minute record at 5 kHz took seconds per limit, and the
discovery's limit search evaluates about twenty. Here the recursion is one compiled loop
with the same IEEE operations per element and step (a subtraction, the clip as a maximum
then a minimum, an addition; NaN propagates as in ``np.clip``), so both give the same
numbers.

Imported only where the kernels are ``fused`` (:func:`es_feedforward.kernels.default_backend`),
as :mod:`es_calibration.model.play_loop`.
"""

from __future__ import annotations

import numba

from es_common.arrays import FloatArray


@numba.njit(cache=True, nogil=True)
def rate_limit_rows(command: FloatArray, step: float, out: FloatArray) -> None:
    """Write ``command`` (N, C) through a limiter of ``step`` per sample into ``out`` (N, C).

    The limiter starts on the first row.
    """
    n, width = command.shape
    if n == 0:
        return
    for j in range(width):
        out[0, j] = command[0, j]
    for i in range(1, n):
        for j in range(width):
            state = out[i - 1, j]
            change = command[i, j] - state
            # comparisons, not min/max: a NaN change stays NaN, as in np.clip
            if change < -step:  # noqa: PLR1730
                change = -step
            if change > step:  # noqa: PLR1730
                change = step
            out[i, j] = state + change
