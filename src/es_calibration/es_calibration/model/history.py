"""The whole command of a block of actuators and first-order low-passes of drive signals.

Effects of the roles ``HEATING`` and ``RELAXATION`` act through a first-order low-pass of a
signal derived from the drive (:meth:`es_physics.effects.Effect.drive_signal`) whose time
constant is an unknown of the fit, as are the parameters that shape the signal, if any
(:attr:`es_physics.effects.Effect.signal_parameters`: the filter is linear, so their
derivatives are the filtered derivatives of the signal). A low-pass needs the whole
history, not only the sampled rows, so :class:`DriveHistory` keeps the block's command and
filters it at full rate (``scipy.signal.lfilter``, vectorised over actuators), caching the
last few results; :class:`DriveSamples` takes the filtered series at a set of sample rows,
with the same command taps (fractional delay) as the voltage in effect.

The command is taken as uniformly sampled at its median period and as varying linearly
between samples (first-order hold: exact for a signal generator's continuous program, and
within a fraction of a period of a held one); around a hole in the command topic the
filtered series is approximate, and the samples there are left out by gaps.py anyway.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
from scipy.signal import lfilter

from es_calibration.errors import CalibrationFitError
from es_common.arrays import FloatArray, IndexArray
from es_physics.effects import Effect

#: Filtered series kept per history (each is the command's size).
CACHE_SIZE: Final = 8

#: A filtered drive signal, its derivative by log tau and those by its signal parameters.
Filtered = tuple[FloatArray, FloatArray, tuple[FloatArray, ...]]


def first_order_lowpass(x: FloatArray, period: float, tau: float) -> tuple[FloatArray, FloatArray]:
    """Return tau dy/dt + y = x for x (N, A) sampled every ``period`` [s], and dy / d(log tau).

    x varies linearly between samples; y starts settled at x[0] (for every tau, so the
    derivative starts at 0). Exact for a piecewise-linear input:
    y_k = D y_(k-1) + (1 - c) x_k + (c - D) x_(k-1), D = exp(-h / tau), c = (1 - D) tau / h;
    the derivative is that recursion differentiated (the same pole, driven by the
    coefficients' derivatives).

    Raises:
        CalibrationFitError: ``period`` or ``tau`` not positive and finite.

    """
    if not (math.isfinite(period) and period > 0.0 and math.isfinite(tau) and tau > 0.0):
        raise CalibrationFitError(f"low-pass needs period > 0 and tau > 0, got {period!r}, {tau!r}")
    if x.shape[0] == 0:
        return np.zeros_like(x), np.zeros_like(x)
    a = period / tau
    one_minus_d = -math.expm1(-a)
    d = 1.0 - one_minus_d
    c = one_minus_d / a
    pole = np.array([1.0, -d])
    b = np.array([1.0 - c, c - d])
    # settled at x[0]: the transposed direct form's state is c x[0] (no solve, so a pole
    # that rounds to 1 for a time constant far beyond the period stays well defined)
    y, _ = lfilter(b, pole, x, axis=0, zi=c * x[:1])
    # d / d(log tau) of D, c and the taps (d a / d(log tau) = -a)
    d_d = a * d
    d_c = (one_minus_d - a * d) / a
    drive = np.zeros_like(x)
    drive[1:] = d_d * y[:-1] - d_c * x[1:] + (d_c - d_d) * x[:-1]
    slope = lfilter([1.0], pole, drive, axis=0)
    return np.asarray(y, np.float64), np.asarray(slope, np.float64)


class DriveHistory:
    """The command of a block of actuators (time-major (N, A) [V]) and its filtered signals."""

    def __init__(self, command: FloatArray, period: float) -> None:
        """Keep ``command`` (non-finite values read as 0) sampled every ``period`` [s]."""
        self.command = np.nan_to_num(np.asarray(command, np.float64))
        self.period = float(period)
        self._signals: dict[tuple[str, tuple[float, ...]], FloatArray] = {}
        self._signal_slopes: dict[tuple[str, tuple[float, ...]], tuple[FloatArray, ...]] = {}
        self._filtered: dict[tuple[str, float, tuple[float, ...]], Filtered] = {}

    def signal(self, effect: Effect, shape: Sequence[float] = ()) -> FloatArray:
        """Return ``effect``'s drive signal (N, A) with signal parameters ``shape``."""
        key = (effect.name, tuple(float(v) for v in shape))
        if key not in self._signals:
            if len(self._signals) >= CACHE_SIZE:
                del self._signals[next(iter(self._signals))]
            self._signals[key] = np.asarray(
                effect.drive_signal(self.command, self.period, key[1]), np.float64
            )
        return self._signals[key]

    def signal_slopes(self, effect: Effect, shape: Sequence[float] = ()) -> tuple[FloatArray, ...]:
        """Return the drive signal's derivatives by each of ``shape`` (each (N, A)).

        They depend on the signal parameters only, not on the time constant a fit varies,
        so one computation serves every low-pass of the same signal.
        """
        key = (effect.name, tuple(float(v) for v in shape))
        if key not in self._signal_slopes:
            if len(self._signal_slopes) >= CACHE_SIZE:
                del self._signal_slopes[next(iter(self._signal_slopes))]
            self._signal_slopes[key] = tuple(
                np.asarray(d, np.float64)
                for d in effect.drive_signal_slopes(self.command, self.period, key[1])
            )
        return self._signal_slopes[key]

    def lowpass(self, effect: Effect, tau: float, shape: Sequence[float] = ()) -> Filtered:
        """Return y = LP_tau(signal), dy / d(log tau) and dy / d each of ``shape``, (N, A).

        Raises:
            CalibrationFitError: ``tau`` not positive and finite.

        """
        key = (effect.name, float(tau), tuple(float(v) for v in shape))
        if key not in self._filtered:
            y, slope = first_order_lowpass(self.signal(effect, shape), self.period, tau)
            slopes = tuple(
                first_order_lowpass(d, self.period, tau)[0]
                for d in self.signal_slopes(effect, key[2])
            )
            if len(self._filtered) >= CACHE_SIZE:
                del self._filtered[next(iter(self._filtered))]
            self._filtered[key] = (y, slope, slopes)
        return self._filtered[key]


@dataclass(frozen=True)
class DriveSamples:
    """A :class:`DriveHistory` read at sample rows through command taps.

    Attributes:
        history: the block's command history.
        taps: (command row of each sample (n,), weight) pairs; a sample's value is the
            weighted sum over the taps (weights sum to 1).

    """

    history: DriveHistory
    taps: tuple[tuple[IndexArray, float], ...]

    def lowpass(self, effect: Effect, tau: float, shape: Sequence[float] = ()) -> Filtered:
        """Return :meth:`DriveHistory.lowpass` at the samples, each (A, n).

        Raises:
            CalibrationFitError: ``tau`` not positive and finite.

        """
        y, slope, slopes = self.history.lowpass(effect, tau, shape)
        return self._at(y), self._at(slope), tuple(self._at(d) for d in slopes)

    def _at(self, series: FloatArray) -> FloatArray:
        """Return a full-rate series (N, A) read at the samples through the taps, (A, n)."""
        return np.asarray(sum(w * series[rows].T for rows, w in self.taps), np.float64)
