"""The first-order low-pass of a drive signal and its tau-derivative, compiled (numba).

:func:`es_calibration.model.history.first_order_lowpass` runs two ``scipy.signal.lfilter``
passes over the whole command (N, A) and a full-size drive array between them; the fits
vary tau at every Levenberg-Marquardt step, so each trial paid both passes at full rate
(about 1.4 s on an 8 x 8 block of a 5-minute record at 500 Hz under load). Here both
recursions run in one compiled loop that keeps only the rows a fit reads. It does the same
IEEE operations in the same order as the numpy path (lfilter's transposed direct form, no
fused multiply-add), so both give the same numbers.

Imported only where the kernels are ``fused`` (:func:`es_feedforward.kernels.default_backend`),
as :mod:`es_calibration.model.play_loop`.
"""

from __future__ import annotations

import numba
import numpy as np

from es_common.arrays import FloatArray, IndexArray


@numba.njit(cache=True, nogil=True)
def lowpass_rows(  # noqa: PLR0917 (numba calls are positional)
    x: FloatArray,
    coefficients: FloatArray,
    keep: IndexArray,
    y_out: FloatArray,
    slope_out: FloatArray,
    with_slope: bool,
) -> None:
    """Filter ``x`` (N, A) and write the rows ``keep`` (increasing, in [0, N)) of y and dy/dlog tau.

    ``coefficients`` are (b0, b1, d, c, d_d, d_c) of :func:`~es_calibration.model.history.
    first_order_lowpass`: y_k = b0 x_k + z_(k-1), z_k = b1 x_k + d y_k, z_(-1) = c x_0; the
    slope is the same pole driven by d_d y_(k-1) - d_c x_k + (d_c - d_d) x_(k-1) from 0.
    ``y_out`` and ``slope_out`` are (len(keep), A); the slope is left alone without
    ``with_slope``.
    """
    b0 = coefficients[0]
    b1 = coefficients[1]
    d = coefficients[2]
    c = coefficients[3]
    d_d = coefficients[4]
    d_c = coefficients[5]
    n_keep = keep.shape[0]
    if n_keep == 0:
        return
    width = x.shape[1]
    z = np.empty(width)
    y_prev = np.empty(width)
    s = np.zeros(width)  # the slope filter's state (its lfilter z)
    for j in range(width):
        z[j] = c * x[0, j]
    slot = 0
    for i in range(keep[n_keep - 1] + 1):
        wanted = keep[slot] == i
        for j in range(width):
            xi = x[i, j]
            y = z[j] + b0 * xi
            z[j] = xi * b1 - y * (-d)
            if wanted:
                y_out[slot, j] = y
            if with_slope:
                drive = 0.0 if i == 0 else d_d * y_prev[j] - d_c * xi + (d_c - d_d) * x[i - 1, j]
                slope = s[j] + drive
                s[j] = drive * 0.0 - slope * (-d)
                y_prev[j] = y
                if wanted:
                    slope_out[slot, j] = slope
        if wanted:
            slot += 1
