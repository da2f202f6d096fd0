"""What the final model leaves unexplained, in statements a person can act on.

Each statement is quantitative: how far the held-out RMS is above the noise floor and what
that excess amounts to; each spectral line with its frequency [Hz] and amplitude [nm], and
whether it is a tone of the command or a low-order combination of its tones (then the drive
makes it, through an effect the candidates miss) or not (a vibration or pickup); each
significant correlation of the residual with V, dV/dt, T, dT/dt or time with its coefficient
and slope (nm per unit of the input), and what effect that dependence points to.
A correlation counts when it exceeds
``CORRELATION_SIGMAS`` times its 95 % bound for an independent residual and its binned means
follow at least ``MIN_EXPLAINED`` of the variance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from es_calibration.search.residual import Dependence, ResidualStructure, spectral_lines, spectrum
from es_common.arrays import BoolArray, FloatArray

NM: Final = 1e9
#: Ratio of held-out RMS to noise floor above which the residual counts as unexplained (and
#: the discovery step searches its library).
NOISE_RATIO_LIMIT: Final = 1.2
#: A correlation must exceed this many times its 95 % bound to be reported.
CORRELATION_SIGMAS: Final = 3.0
#: Smallest share of the residual variance a reported dependence must carry.
MIN_EXPLAINED: Final = 0.02
#: Mains frequencies whose harmonics a spectral line is checked against [Hz].
MAINS_HZ: Final = (50.0, 60.0)
#: Highest order (sum of |integer coefficients|) of a combination of the command's tones that
#: a residual line is matched against, and how many of the strongest tones take part.
MAX_ORDER: Final = 4
MAX_TONES: Final = 3

#: What a dependence on each input points to (keys: the regressor names of the analysis).
_HINTS: Final = {
    "V": "the law's shape in V is off: a drive-side effect (hysteresis) or another law form",
    "dV/dt": "a rate dependence: a timing error between command and displacement, "
    "rate-dependent hysteresis or actuator dynamics",
    "T": "a temperature dependence the law misses: a sensor offset, thermal expansion or "
    "curvature of M(T), k(T)",
    "dT/dt": "the actuator temperature leads or lags its sensor (sensor lag) or heats itself",
    "time": "a drift over the record: aging, creep or a slow drift of the interferometer",
}


@dataclass(frozen=True)
class Drive:
    """What the drive does on the analysed rows, to interpret the residual.

    Attributes:
        gain_m_per_v: median least-squares slope dz/dV over actuators [m/V] (NaN: unknown).
        tones_hz: frequencies of the command's strongest spectral lines [Hz].
        resolution_hz: spectral bin spacing [Hz].

    """

    gain_m_per_v: float
    tones_hz: tuple[float, ...]
    resolution_hz: float

    def combination(self, freq: float) -> str | None:
        """Return the lowest-order combination of the tones within a bin of ``freq``, or None.

        E.g. "2 x 1.10 Hz +1 x 2.70 Hz"; orders up to ``MAX_ORDER``.
        """
        tones = np.asarray(self.tones_hz)
        if tones.size == 0:
            return None
        grids = np.meshgrid(*[np.arange(-MAX_ORDER, MAX_ORDER + 1)] * tones.size, indexing="ij")
        coef = np.stack([g.ravel() for g in grids], axis=1)
        order = np.abs(coef).sum(axis=1)
        near = np.abs(np.abs(coef @ tones) - freq) <= self.resolution_hz
        ok = np.flatnonzero((order >= 1) & (order <= MAX_ORDER) & near)
        if ok.size == 0:
            return None
        best = coef[ok[np.argmin(order[ok])]]
        if best @ tones < 0:
            best = -best
        terms = [f"{c:+d} x {f:.2f} Hz" for c, f in zip(best, tones, strict=True) if c]
        return " ".join(terms).lstrip("+")


def drive_tones(voltage: FloatArray, contiguous: BoolArray, rate: float) -> tuple[float, ...]:
    """Return the frequencies [Hz] of the command's strongest spectral lines (``MAX_TONES``).

    Args:
        voltage: command in effect (A, n) [V].
        contiguous: (n - 1,) whether consecutive rows are neighbours in time.
        rate: sample rate [Hz].

    """
    centred = voltage - np.nanmean(voltage, axis=1, keepdims=True)
    f, psd, segments = spectrum(centred, contiguous, rate)
    finite = centred[np.isfinite(centred)]
    variance = float(np.mean(finite * finite)) if finite.size else 0.0
    return tuple(freq for freq, _ in spectral_lines(f, psd, segments, variance)[:MAX_TONES])


def drive_gain(voltage: FloatArray, displacement: FloatArray) -> float:
    """Return the median over actuators of the least-squares slope dz/dV [m/V].

    Args:
        voltage: command in effect (A, n) [V].
        displacement: measured displacement (A, n) [m]; NaN where dropped.

    """
    ok = np.isfinite(voltage) & np.isfinite(displacement)
    n = np.maximum(ok.sum(axis=1), 1)
    v = np.where(ok, voltage, 0.0)
    z = np.where(ok, displacement, 0.0)
    vc = np.where(ok, v - (v.sum(axis=1) / n)[:, None], 0.0)
    zc = np.where(ok, z - (z.sum(axis=1) / n)[:, None], 0.0)
    den = np.sum(vc * vc, axis=1)
    slopes = np.sum(vc * zc, axis=1)[den > 0] / den[den > 0]
    return float(np.median(slopes)) if slopes.size else float("nan")


def _mains(freq: float) -> str:
    for mains in MAINS_HZ:
        k = round(freq / mains)
        if k >= 1 and abs(freq - k * mains) < 0.01 * mains:
            return f" ({'mains' if k == 1 else f'harmonic {k} of the'} {mains:g} Hz mains?)"
    return ""


def _line(freq: float, rms: float, variance: float, context: Drive) -> str:
    share = 100.0 * rms * rms / variance if variance > 0 else float("nan")
    text = (
        f"spectral line at {freq:.2f} Hz: amplitude {np.sqrt(2.0) * rms * NM:.3g} nm "
        f"({rms * NM:.3g} nm rms, {share:.0f} % of the residual variance)"
    )
    made = context.combination(freq)
    if made:
        return text + (
            f"; the command's tones make it ({made}): the drive acts through an effect no "
            "candidate describes"
        )
    return text + (
        "; no tone of the command or low-order combination of them lies there: look for a "
        f"vibration or pickup at {freq:.2f} Hz{_mains(freq)}"
    )


def _dependence(dep: Dependence, gain_m_per_v: float) -> str:
    """Return one statement on a significant dependence of the residual on an input."""
    text = (
        f"residual correlates with {dep.name} (r = {dep.correlation:+.3f}, 95 % bound "
        f"{dep.correlation_bound:.3f}; slope {dep.slope * NM:+.3g} nm per {dep.unit}; "
        f"{100 * dep.explained_fraction:.1f} % of the variance follows it)"
    )
    hint = _HINTS.get(dep.name)
    if hint:
        text += f": {hint}"
    if dep.name == "dV/dt" and np.isfinite(gain_m_per_v) and gain_m_per_v != 0:
        # z(t) = f(V(t - d)) ~ f(V) - f'(V) d dV/dt, so the slope is -gain * d
        lag = -dep.slope / gain_m_per_v
        way = "lags" if lag > 0 else "leads"
        text += (
            f"; with the mean gain {gain_m_per_v * NM:.3g} nm/V this is as if the displacement "
            f"{way} the modelled response by {abs(lag) * 1e3:.3g} ms"
        )
    if dep.name == "time":
        text += f" ({dep.slope * NM * 3600.0:+.3g} nm per hour)"
    return text


def _duration(seconds: float) -> str:
    return f"{seconds:.3g} s" if seconds >= 1.0 else f"{seconds * 1e3:.3g} ms"


def describe(after: ResidualStructure, final_rms: float, ratio_limit: float) -> list[str]:
    """Return statements on the structure the final model leaves (empty: only noise).

    Args:
        after: structure of the final held-out residual.
        final_rms: held-out RMS of the final model on the whole grid [m].
        ratio_limit: ratio of ``final_rms`` to the noise floor above which the residual
            counts as unexplained.

    """
    f = after.frequencies
    context = Drive(
        after.drive_gain_m_per_v,
        after.drive_tones_hz,
        float(f[1] - f[0]) if f.size > 1 else float("nan"),
    )
    notes = []
    floor = after.noise_floor
    if np.isfinite(floor) and floor > 0 and final_rms > ratio_limit * floor:
        excess = np.sqrt(max(final_rms**2 - floor**2, 0.0))
        notes.append(
            f"held-out RMS {final_rms * NM:.3g} nm is {final_rms / floor:.2f} x the noise floor "
            f"{floor * NM:.3g} nm: about {excess * NM:.3g} nm rms is structure no candidate "
            "explains"
        )
    variance = after.rms * after.rms
    notes += [_line(freq, rms, variance, context) for freq, rms in after.lines]
    notes += [
        _dependence(dep, context.gain_m_per_v)
        for dep in after.dependences
        if abs(dep.correlation) > CORRELATION_SIGMAS * dep.correlation_bound
        and dep.explained_fraction > MIN_EXPLAINED
    ]
    significant = np.abs(after.autocorrelation[1:]) > after.autocorrelation_bound
    if after.tau_int > 2.0 and significant.mean() > 0.2:
        period = float(after.lags_s[1]) if after.lags_s.size > 1 else float("nan")
        notes.append(
            f"residual is autocorrelated over about {_duration(after.tau_int * period)} "
            f"(integrated time {after.tau_int:.1f} samples): slow structure remains"
        )
    return notes
