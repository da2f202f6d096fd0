"""Self-heating's drive signal and its slope by the mean window, compiled (numba).

The self-heating candidate's fit varies the running-mean window W at every
Levenberg-Marquardt step, so the drive signal P_drive (:meth:`es_physics.effects.
self_heating.SelfHeating.drive_signal`) and its derivative by log W
(:meth:`~es_physics.effects.self_heating.SelfHeating.drive_signal_slopes`) are recomputed
over the whole command at every step: three ``lfilter`` passes and a dozen full-size numpy
operations, about 0.3 s a step on an 8 x 8 block of a 5-minute record at 500 Hz (40 of the
87 s of a 32 x 32 calibration's effect search). Here both come out of one compiled pass. It
does the same IEEE operations in the same order as the numpy path (lfilter's transposed
direct form for the running mean and its slope, no fused multiply-add), so both give the
same numbers (tests/es_calibration/test_caches.py).

Imported only where the kernels are ``fused`` (:func:`es_feedforward.kernels.default_backend`),
as :mod:`es_calibration.model.lowpass_loop`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np

from es_common.arrays import FloatArray
from es_physics.effects import Effect
from es_physics.effects.self_heating import SelfHeating


@numba.njit(cache=True, nogil=True)
def loss_signal_rows(  # noqa: PLR0917 (numba calls are positional)
    command: FloatArray,
    period: float,
    keep: float,
    slope_scale: float,
    with_slope: bool,
    signal_out: FloatArray,
    slope_out: FloatArray,
) -> None:
    """Write P_drive and d P_drive / d log W of ``command`` (N, A) into the outputs (N, A).

    The running mean m_0 = V_0, m_k = keep m_(k-1) + (1 - keep) V_(k-1); its slope
    s_0 = 0, s_k = keep s_(k-1) + (m_(k-1) - V_(k-1)) ``slope_scale`` (keep period / W);
    row 0 of both outputs is 0, the slope all 0 without ``with_slope``. ``command`` finite.
    """
    n, width = command.shape
    # lfilter's transposed direct form: each output is its state, then the state becomes
    # b1 x - a1 y (b0 = 0 for both filters)
    mean_state = np.empty(width)
    slope_state = np.zeros(width)
    b1 = 1.0 - keep
    for j in range(width):
        mean_state[j] = command[0, j]
    for i in range(n):
        for j in range(width):
            current = command[i, j]
            mean = mean_state[j]
            mean_state[j] = current * b1 - mean * (-keep)
            slope = 0.0
            if with_slope:
                slope = slope_state[j]
                slope_state[j] = (mean - current) * slope_scale * 1.0 - slope * (-keep)
            if i == 0:
                signal_out[0, j] = 0.0
                slope_out[0, j] = 0.0
                continue
            previous = command[i - 1, j]
            swing = abs(current - previous)
            level = 0.5 * (current + previous) - mean
            signal_out[i, j] = 0.5 * swing * abs(level) / period
            sign = 1.0 if level > 0.0 else (-1.0 if level < 0.0 else 0.0)
            slope_out[i, j] = -0.5 * swing * sign * slope / period


def fused_drive_signal(
    effect: Effect, command: FloatArray, period: float, shape: Sequence[float]
) -> tuple[FloatArray, tuple[FloatArray, ...]] | None:
    """Return ``effect``'s drive signal and its slopes from one compiled pass, or None.

    None for an effect without a compiled twin (every one but self-heating).
    """
    if not isinstance(effect, SelfHeating):
        return None
    command = np.ascontiguousarray(command, np.float64)
    signal = np.zeros_like(command)
    slope = np.zeros_like(command)
    if command.shape[0] < 2:
        return signal, (slope,)
    window, inside = effect.mean_window(shape)
    keep = math.exp(-period / window)
    loss_signal_rows(command, period, keep, keep * period / window, inside, signal, slope)
    return signal, (slope,)
