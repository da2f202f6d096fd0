"""Signal operators of the test stand.

Play (backlash) and Prandtl-Ishlinskii hysteresis, first-order lags, Debye relaxation, aging
gain and the face-sheet Laplacian.

Pure numpy/scipy, time along axis 0, vectorised over the actuators; written for the stand
alone (no code shared with the project's plant or calibration).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from standgen._typing import FloatArray


def play(x: npt.ArrayLike, thresholds: npt.ArrayLike) -> FloatArray:
    """Play (backlash) operators of half-widths ``thresholds`` on the sequence ``x``.

    p[0] = x[0] (the operator starts at rest on the input), then
    p[k] = min(max(p[k-1], x[k] - r), x[k] + r): the output follows the input only once it is
    more than r away, so |x - p| <= r at every sample.

    Args:
        x: input samples (N, ...) [V].
        thresholds: half-widths r >= 0 [V], shape (n,) (n operators, same for every
            actuator) or (n, ...) matching ``x.shape[1:]``.

    Returns:
        (n, N, ...) operator outputs [V].

    Raises:
        ValueError: a negative threshold, or ``x`` without samples.

    """
    xs = np.asarray(x, np.float64)
    r = np.atleast_1d(np.asarray(thresholds, np.float64))
    if xs.shape[0] == 0:
        raise ValueError("play operator needs at least one sample")
    if np.any(r < 0):
        raise ValueError("play thresholds must be >= 0")
    r = r.reshape(r.shape + (1,) * (xs.ndim - r.ndim))  # (n, ...) broadcast to a sample
    out = np.empty((len(r), *xs.shape), np.float64)
    state = np.broadcast_to(xs[0], out.shape[:1] + xs.shape[1:]).copy()
    low = xs[:, None] - r[None]
    high = xs[:, None] + r[None]
    for i in range(xs.shape[0]):
        np.minimum(np.maximum(state, low[i]), high[i], out=state)
        out[:, i] = state
    return out


def prandtl_ishlinskii(x: npt.ArrayLike, thresholds: npt.ArrayLike,
                       weights: npt.ArrayLike) -> FloatArray:
    """Drive-side PI hysteresis: (1 - sum w) x + sum_i w_i play_{r_i}(x).

    Args:
        x: drive samples (N, ...) [V].
        thresholds: (n,) or (n, ...) half-widths [V].
        weights: non-negative weights, same shape as ``thresholds``, sum <= 1.

    Returns:
        effective drive (N, ...) [V].

    Raises:
        ValueError: negative weights or thresholds, or weights summing above 1.

    """
    w = np.asarray(weights, np.float64)
    if np.any(w < 0) or np.any(w.sum(axis=0) > 1.0):
        raise ValueError("PI weights must be >= 0 and sum to at most 1")
    xs = np.asarray(x, np.float64)
    plays = play(xs, thresholds)
    w = w.reshape(w.shape + (1,) * (plays.ndim - 1 - w.ndim))[:, None]
    return np.asarray((1.0 - w.sum(axis=0)) * xs + (w * plays).sum(axis=0), np.float64)


def first_order_lag(x: npt.ArrayLike, dt: float, tau: npt.ArrayLike) -> FloatArray:
    """Exact first-order lag tau dy/dt = x - y of samples ``x`` (N, ...) held over ``dt`` [s].

    Starts in steady state (y[0] = x[0]). ``tau`` [s] is a scalar (tau = 0 returns ``x``).

    Raises:
        ValueError: negative ``tau`` or non-positive ``dt``.

    """
    xs = np.asarray(x, np.float64)
    t = float(np.asarray(tau))
    if t < 0 or dt <= 0:
        raise ValueError("lag needs tau >= 0 and dt > 0")
    if t == 0:
        return xs.copy()
    a = float(np.exp(-dt / t))
    y, _ = lfilter([1.0 - a], [1.0, -a], xs, axis=0, zi=a * xs[:1])
    return np.asarray(y, np.float64)


def debye_relaxation(x: npt.ArrayLike, dt: float, strength: float,
                     corner_hz: float) -> FloatArray:
    """Frequency dispersion of the polarisation: (1 - s) x + s lowpass_fc(x).

    The drive reaches the polarisation in full below the corner ``corner_hz`` and reduced by
    the factor (1 - ``strength``) well above it (a Debye relaxation), so the displacement gain
    falls with the drive frequency.

    Raises:
        ValueError: ``strength`` outside [0, 1) or a non-positive corner.

    """
    if not 0 <= strength < 1 or corner_hz <= 0:
        raise ValueError("Debye relaxation needs 0 <= strength < 1 and corner > 0")
    xs = np.asarray(x, np.float64)
    slow = first_order_lag(xs, dt, 1.0 / (2 * np.pi * corner_hz))
    return np.asarray((1.0 - strength) * xs + strength * slow, np.float64)


def aging_gain(t: npt.ArrayLike, fraction: float, tau_s: float, nu: float) -> FloatArray:
    """Aging of M: D = D0 + D1 exp(-(t/tau)^nu) with D0 = 1 - a, D1 = a (t >= 0 [s]).

    Returns 1 at t = 0, falling towards 1 - ``fraction``.
    """
    ts = np.maximum(np.asarray(t, np.float64), 0.0)
    return np.asarray(1.0 - fraction + fraction * np.exp(-((ts / tau_s) ** nu)), np.float64)


def laplacian(z: npt.ArrayLike) -> FloatArray:
    """4-neighbour discrete Laplacian over the last two axes (rows, cols).

    lap(z)[i, j] = sum over existing neighbours n of (z[n] - z[i, j]); edges and corners have
    only their existing neighbours.
    """
    zs = np.asarray(z, np.float64)
    out = np.zeros_like(zs)
    out[..., 1:, :] += zs[..., :-1, :] - zs[..., 1:, :]
    out[..., :-1, :] += zs[..., 1:, :] - zs[..., :-1, :]
    out[..., :, 1:] += zs[..., :, :-1] - zs[..., :, 1:]
    out[..., :, :-1] += zs[..., :, 1:] - zs[..., :, :-1]
    return out
