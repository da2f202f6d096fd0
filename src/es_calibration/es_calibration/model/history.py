"""The whole command of a block of actuators and first-order low-passes of drive signals.

Effects of the roles ``HEATING`` and ``RELAXATION`` act through a first-order low-pass of a
signal derived from the drive (:meth:`es_physics.effects.Effect.drive_signal`) whose time
constant is an unknown of the fit, as are the parameters that shape the signal, if any
(:attr:`es_physics.effects.Effect.signal_parameters`: the filter is linear, so their
derivatives are the filtered derivatives of the signal). A low-pass needs the whole
history, not only the sampled rows, so :class:`DriveHistory` keeps the block's command and
filters all of it, keeping the rows a fit reads (one compiled pass where the kernels are
fused, :mod:`.lowpass_loop`, and self-heating's signal with its slope in another,
:mod:`.heating_loop`; else ``scipy.signal.lfilter``, vectorised over actuators),
caching the results by what they depend on; :class:`DriveSamples` takes the filtered series
at a set of sample rows, with the same command taps (fractional delay) as the voltage in
effect.

The command is taken as uniformly sampled at its median period and as varying linearly
between samples (first-order hold: exact for a signal generator's continuous program, and
within a fraction of a period of a held one); around a hole in the command topic the
filtered series is approximate, and the samples there are left out by gaps.py anyway.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Final

import numpy as np
from scipy.signal import lfilter

from es_calibration.errors import CalibrationFitError
from es_calibration.model.cache import DEFAULT_BUDGET_BYTES, BoundedCache, rows_key
from es_common.arrays import FloatArray, IndexArray
from es_feedforward.kernels import Backend, default_backend
from es_physics.effects import Effect

#: Drive signals (and their slopes) kept per history (each is the command's size).
CACHE_SIZE: Final = 4

#: A filtered drive signal, its derivative by log tau and those by its signal parameters.
Filtered = tuple[FloatArray, FloatArray, tuple[FloatArray, ...]]


def _coefficients(period: float, tau: float) -> tuple[float, float, float, float, float, float]:
    """Return (b0, b1, d, c, d_d, d_c) of the low-pass (see :func:`first_order_lowpass`).

    Raises:
        CalibrationFitError: ``period`` or ``tau`` not positive and finite.

    """
    if not (math.isfinite(period) and period > 0.0 and math.isfinite(tau) and tau > 0.0):
        raise CalibrationFitError(f"low-pass needs period > 0 and tau > 0, got {period!r}, {tau!r}")
    a = period / tau
    one_minus_d = -math.expm1(-a)
    d = 1.0 - one_minus_d
    c = one_minus_d / a
    # d / d(log tau) of D and c (d a / d(log tau) = -a)
    d_d = a * d
    d_c = (one_minus_d - a * d) / a
    return 1.0 - c, c - d, d, c, d_d, d_c


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
    b0, b1, d, c, d_d, d_c = _coefficients(period, tau)
    if x.shape[0] == 0:
        return np.zeros_like(x), np.zeros_like(x)
    pole = np.array([1.0, -d])
    # settled at x[0]: the transposed direct form's state is c x[0] (no solve, so a pole
    # that rounds to 1 for a time constant far beyond the period stays well defined)
    y, _ = lfilter(np.array([b0, b1]), pole, x, axis=0, zi=c * x[:1])
    drive = np.zeros_like(x)
    drive[1:] = d_d * y[:-1] - d_c * x[1:] + (d_c - d_d) * x[:-1]
    slope = lfilter([1.0], pole, drive, axis=0)
    return np.asarray(y, np.float64), np.asarray(slope, np.float64)


def lowpass_at(
    x: FloatArray, period: float, tau: float, rows: IndexArray, *, with_slope: bool = True
) -> tuple[FloatArray, FloatArray]:
    """Return :func:`first_order_lowpass` of ``x`` (N, A) read at ``rows``, each (len(rows), A).

    ``rows`` increasing, in [0, N). Without ``with_slope`` the slope is zeros. Where the
    kernels are fused, one compiled pass that keeps only those rows
    (:mod:`es_calibration.model.lowpass_loop`, the same numbers); else the two full-rate
    lfilter passes.

    Raises:
        CalibrationFitError: ``period`` or ``tau`` not positive and finite.

    """
    coefficients = _coefficients(period, tau)
    rows = np.asarray(rows, np.intp)
    shape = (rows.size, *x.shape[1:])
    if rows.size == 0 or x.shape[0] == 0:
        return np.zeros(shape), np.zeros(shape)
    if default_backend() is not Backend.FUSED:
        y, slope = first_order_lowpass(x, period, tau)
        return y[rows], slope[rows] if with_slope else np.zeros(shape)
    from es_calibration.model.lowpass_loop import lowpass_rows

    flat = np.ascontiguousarray(x.reshape(x.shape[0], -1), np.float64)
    y_out = np.empty((rows.size, flat.shape[1]))
    slope_out = np.zeros_like(y_out)
    lowpass_rows(flat, np.array(coefficients), rows, y_out, slope_out, with_slope)
    return y_out.reshape(shape), slope_out.reshape(shape)


class DriveHistory:
    """The command of a block of actuators (time-major (N, A) [V]) and its filtered signals.

    Drive signals are kept by (effect, signal parameters), their low-passes by (effect, tau,
    signal parameters, rows read): a fit's trial and its Jacobian at the same values, and
    every later fit or score at a time constant met before, reuse them
    (:class:`~es_calibration.model.cache.BoundedCache`, within ``budget_bytes``).
    """

    def __init__(
        self, command: FloatArray, period: float, budget_bytes: int = DEFAULT_BUDGET_BYTES
    ) -> None:
        """Keep ``command`` (non-finite values read as 0) sampled every ``period`` [s]."""
        self.command = np.nan_to_num(np.asarray(command, np.float64))
        self.period = float(period)
        self._signals: BoundedCache[FloatArray] = BoundedCache(budget_bytes, CACHE_SIZE)
        self._signal_slopes: BoundedCache[tuple[FloatArray, ...]] = BoundedCache(
            budget_bytes, CACHE_SIZE
        )
        self._filtered: BoundedCache[Filtered] = BoundedCache(budget_bytes)

    def _fused(
        self, effect: Effect, key: tuple[str, tuple[float, ...]]
    ) -> tuple[FloatArray, tuple[FloatArray, ...]] | None:
        """Return the signal and its slopes from one compiled pass (kept), or None.

        None unless the kernels are fused and the effect has a compiled twin
        (:mod:`.heating_loop`).
        """
        if default_backend() is not Backend.FUSED:
            return None
        from es_calibration.model.heating_loop import fused_drive_signal

        both = fused_drive_signal(effect, self.command, self.period, key[1])
        if both is not None:
            self._signals.put(key, both[0])
            self._signal_slopes.put(key, both[1])
        return both

    def signal(self, effect: Effect, shape: Sequence[float] = ()) -> FloatArray:
        """Return ``effect``'s drive signal (N, A) with signal parameters ``shape``."""
        key = (effect.name, tuple(float(v) for v in shape))
        found = self._signals.get(key)
        if found is None and (both := self._fused(effect, key)) is not None:
            found = both[0]
        if found is None:
            found = self._signals.put(
                key, np.asarray(effect.drive_signal(self.command, self.period, key[1]), np.float64)
            )
        return found

    def signal_slopes(self, effect: Effect, shape: Sequence[float] = ()) -> tuple[FloatArray, ...]:
        """Return the drive signal's derivatives by each of ``shape`` (each (N, A)).

        They depend on the signal parameters only, not on the time constant a fit varies,
        so one computation serves every low-pass of the same signal.
        """
        key = (effect.name, tuple(float(v) for v in shape))
        found = self._signal_slopes.get(key)
        if found is None and (both := self._fused(effect, key)) is not None:
            found = both[1]
        if found is None:
            found = self._signal_slopes.put(
                key,
                tuple(
                    np.asarray(d, np.float64)
                    for d in effect.drive_signal_slopes(self.command, self.period, key[1])
                ),
            )
        return found

    def lowpass(
        self,
        effect: Effect,
        tau: float,
        shape: Sequence[float] = (),
        rows: IndexArray | None = None,
    ) -> Filtered:
        """Return y = LP_tau(signal), dy / d(log tau) and dy / d each of ``shape``.

        Each (N, A), or (len(rows), A) at ``rows`` (increasing, in [0, N)) when given.

        Raises:
            CalibrationFitError: ``tau`` not positive and finite.

        """
        at = np.arange(self.command.shape[0]) if rows is None else np.asarray(rows, np.intp)
        key = (effect.name, float(tau), tuple(float(v) for v in shape), rows_key(at))
        found = self._filtered.get(key)
        if found is None:
            y, slope = lowpass_at(self.signal(effect, shape), self.period, tau, at)
            slopes = tuple(
                lowpass_at(d, self.period, tau, at, with_slope=False)[0]
                for d in self.signal_slopes(effect, key[2])
            )
            found = self._filtered.put(key, (y, slope, slopes))
        return found


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

    @cached_property
    def _rows(self) -> tuple[IndexArray, tuple[IndexArray, ...]]:
        """Return the command rows any tap reads (increasing) and each tap's places in them."""
        rows = np.unique(np.concatenate([r for r, _ in self.taps])) if self.taps else np.zeros(
            0, np.intp
        )
        return rows, tuple(np.searchsorted(rows, r) for r, _ in self.taps)

    def lowpass(self, effect: Effect, tau: float, shape: Sequence[float] = ()) -> Filtered:
        """Return :meth:`DriveHistory.lowpass` at the samples, each (A, n).

        Raises:
            CalibrationFitError: ``tau`` not positive and finite.

        """
        rows, _ = self._rows
        y, slope, slopes = self.history.lowpass(effect, tau, shape, rows)
        return self._at(y), self._at(slope), tuple(self._at(d) for d in slopes)

    def _at(self, series: FloatArray) -> FloatArray:
        """Return a series read at the taps' rows (len(rows), A) at the samples, (A, n)."""
        _, places = self._rows
        return np.asarray(
            sum(w * series[p].T for p, (_, w) in zip(places, self.taps, strict=True)), np.float64
        )
