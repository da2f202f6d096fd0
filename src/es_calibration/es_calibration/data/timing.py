"""Timing health of a recording: clock-rate difference between loggers, stamp jitter, bursts.

Pure functions on stamps and per-block delays (the delays themselves are measured by
search/blockdelay.py with the plain law), returning dataclasses and health findings
(health/findings.py).

- **Clock rate.** Command and displacement logged on two clocks that run at different rates
  show a command-to-displacement delay that grows (or shrinks) linearly over the record: a
  displacement clock fast by e (a fraction; ppm = e 1e6) stamps the instant t at
  t0 + (t - t0)(1 + e), so the apparent delay is d + e (t - t0). The slope of a straight line
  through the blocks' delays is e. It is taken as real when it is ``MIN_T_RATIO`` times its
  standard error and moves the delay by ``MIN_DRIFT_PERIODS`` command periods over the
  record (less is below the delay's own resolution and harmless); the displacement time base
  is then corrected, t_true = t0 + (t_stamp - t0) / (1 + e).
- **Jitter.** The spread of a topic's stamp intervals about their median (robust: 1.4826 x
  the median absolute deviation), reported above ``JITTER_LIMIT`` of the median period.
- **Late bursts.** A run of bunched stamps (intervals below ``BUNCHED`` of the median period)
  after a gap that holds its first message back by more than ``BURST_MIN_PERIODS`` periods
  and ``BURST_JITTER_SIGMAS`` times the jitter: messages held up and delivered together,
  their stamps the receive times, up to the gap late. Shorter bunching is the jitter itself.
  The displacement samples of a late burst are left out by align.py (their sampling times
  are unknown); the command's are reported.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from es_calibration.health.findings import Finding
from es_common.arrays import BoolArray, FloatArray

#: A clock-rate slope counts when it is this many standard errors from zero...
MIN_T_RATIO: Final = 6.0
#: ... and moves the delay by at least this many command periods over the record.
MIN_DRIFT_PERIODS: Final = 0.1
#: Stamp jitter (robust sd of the intervals) reported above this fraction of the period.
JITTER_LIMIT: Final = 0.05
#: An interval shorter than this fraction of the median period is bunched.
BUNCHED: Final = 0.5
#: A bunched run is a late burst when its first message is held back by more than this many
#: periods ...
BURST_MIN_PERIODS: Final = 10.0
#: ... and this many times the stamps' jitter (robust sd of the intervals).
BURST_JITTER_SIGMAS: Final = 10.0
#: Late bursts listed one by one at most (the rest summed into the last finding).
MAX_BURSTS: Final = 10


@dataclass(frozen=True)
class LateBurst:
    """Messages ``first`` .. ``last`` (stamp order) delivered together, ``late_s`` late.

    ``late_s`` is how long the first of them was held back beyond one period [s].
    """

    first: int
    last: int
    late_s: float


@dataclass(frozen=True)
class ClockRate:
    """The displacement clock's rate against the command's, from per-block delays.

    Attributes:
        ppm: the displacement clock's excess rate [ppm] (positive: it runs fast).
        sigma_ppm: its standard error [ppm].
        block_times_s: (B,) the blocks' centre times (s from the record's start).
        block_delays_s: (B,) the delay measured in each block [s].
        drift_s: the delay's change over the record [s].
        significant: whether the rate is real (see the module docstring) and corrected.

    """

    ppm: float
    sigma_ppm: float
    block_times_s: FloatArray
    block_delays_s: FloatArray
    drift_s: float
    significant: bool

    @property
    def fraction(self) -> float:
        """Return the rate difference as a fraction (ppm 1e-6)."""
        return self.ppm * 1e-6


def clock_rate(
    block_times_s: FloatArray,
    block_delays_s: FloatArray,
    block_sigmas_s: FloatArray,
    period_s: float,
    duration_s: float,
) -> ClockRate:
    """Return the clock-rate difference the blocks' delays show (a weighted straight line).

    Args:
        block_times_s: (B,) centre times of the blocks (s from the record's start).
        block_delays_s: (B,) delay measured in each block [s] (NaN: not measured).
        block_sigmas_s: (B,) each delay's standard deviation [s] (the weights; inflated
            by the line's own scatter when that is larger).
        period_s: the command period [s].
        duration_s: the record's length [s].

    """
    # the delay scan's own resolution floors each sd (no block is infinitely sure)
    sd = np.maximum(block_sigmas_s, 1e-3 * period_s)
    ok = np.isfinite(block_delays_s) & np.isfinite(sd)
    t, d, w = block_times_s[ok], block_delays_s[ok], 1.0 / sd[ok] ** 2
    if t.size < 3 or np.ptp(t) <= 0.0:
        return ClockRate(0.0, np.inf, block_times_s, block_delays_s, 0.0, False)
    tc = t - np.sum(w * t) / np.sum(w)
    mean = np.sum(w * d) / np.sum(w)
    spread = float(np.sum(w * tc * tc))
    slope = float(np.sum(w * tc * (d - mean)) / spread)
    chi2 = float(np.sum(w * (d - mean - slope * tc) ** 2)) / (t.size - 2)
    sigma = float(np.sqrt(max(chi2, 1.0) / spread))
    drift = slope * duration_s
    significant = abs(slope) >= MIN_T_RATIO * sigma and abs(drift) >= MIN_DRIFT_PERIODS * period_s
    return ClockRate(slope * 1e6, sigma * 1e6, block_times_s, block_delays_s, drift, significant)


def corrected_times(times: FloatArray, fraction: float, origin: float) -> FloatArray:
    """Return stamps ``times`` [s] of a clock fast by ``fraction`` on the reference clock.

    ``origin`` [s] is where both clocks agree (the record's start).
    """
    return np.asarray(origin + (times - origin) / (1.0 + fraction), np.float64)


def clock_rate_finding(rate: ClockRate, duration_s: float) -> Finding:
    """Return the "clock_rate" finding of a significant ``rate`` over ``duration_s`` [s]."""
    side = "fast" if rate.ppm > 0 else "slow"
    return Finding(
        kind="clock_rate",
        subject="displacement logger",
        index=None,
        row=None,
        col=None,
        start_s=0.0,
        end_s=duration_s,
        value=rate.ppm,
        unit="ppm",
        sentence=(
            f"The displacement logger's clock runs {abs(rate.ppm):.1f} ppm {side} against the "
            f"command's (+-{rate.sigma_ppm:.1f} ppm): the command-to-displacement delay drifts "
            f"by {abs(rate.drift_s) * 1e3:.2f} ms over the {duration_s:.0f} s record."
        ),
        action="time base corrected",
    )


def _robust_sd(x: FloatArray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def _intervals(times: FloatArray) -> tuple[FloatArray, float] | None:
    """Return sorted stamps' intervals and their median period, or None (too few, no period)."""
    steps = np.diff(times)
    if steps.size < 10:
        return None
    period = float(np.median(steps))
    return (steps, period) if period > 0.0 else None


def receive_jitter(times: FloatArray) -> float:
    """Return the jitter [s rms] of sorted stamps ``times`` above ``JITTER_LIMIT``, else 0."""
    if (intervals := _intervals(times)) is None:
        return 0.0
    steps, period = intervals
    jitter = _robust_sd(steps - period)
    return jitter if jitter > JITTER_LIMIT * period else 0.0


def late_bursts(times: FloatArray) -> list[LateBurst]:
    """Return the late bursts (see the module) of one topic's sorted stamps ``times`` [s]."""
    if (intervals := _intervals(times)) is None:
        return []
    steps, period = intervals
    bunched = steps < BUNCHED * period
    if not bunched.any():
        return []
    held = max(BURST_MIN_PERIODS * period, BURST_JITTER_SIGMAS * _robust_sd(steps - period))
    # steps a .. b - 1 bunched: messages a .. b arrived together after the gap steps[a - 1]
    starts = np.flatnonzero(bunched & ~np.r_[False, bunched[:-1]])
    stops = np.flatnonzero(bunched & ~np.r_[bunched[1:], False]) + 1
    late = steps[np.maximum(starts - 1, 0)] - period
    keep = (starts > 0) & (late > held)
    return [LateBurst(int(a), int(b), float(d))
            for a, b, d in zip(starts[keep], stops[keep], late[keep], strict=True)]


def late_burst_messages(times: FloatArray) -> BoolArray:
    """Return which of the sorted stamps ``times`` belong to a late burst."""
    out = np.zeros(times.shape, dtype=bool)
    for burst in late_bursts(times):
        out[burst.first : burst.last + 1] = True
    return out


def stamp_findings(
    subject: str, times: FloatArray, origin: float, *, burst_action: str
) -> list[Finding]:
    """Return the jitter and late-burst findings of one topic's sorted stamps ``times`` [s].

    ``subject`` names the topic's logger ("displacement logger"), ``origin`` [s] is the
    record's start (finding times are since it), ``burst_action`` says what the calibration
    does with a late burst's messages.
    """
    if (intervals := _intervals(times)) is None:
        return []
    period = intervals[1]
    out: list[Finding] = []
    end = float(times[-1] - origin)
    jitter = receive_jitter(times)
    if jitter:
        out.append(Finding(
            kind="receive_jitter", subject=subject, index=None, row=None, col=None,
            start_s=float(times[0] - origin), end_s=end, value=jitter * 1e3, unit="ms rms",
            sentence=(
                f"The {subject}'s stamps jitter by {jitter * 1e3:.3f} ms rms about their "
                f"{period * 1e3:.3f} ms period ({100 * jitter / period:.0f} %): the stamps are "
                "receive times, not sampling times."
            ),
            action="reported; stamps used as recorded",
        ))
    bursts = late_bursts(times)
    for k, burst in enumerate(bursts[:MAX_BURSTS]):
        a, b = burst.first, burst.last
        more = len(bursts) - MAX_BURSTS if k == MAX_BURSTS - 1 else 0
        out.append(Finding(
            kind="late_burst", subject=subject, index=None, row=None, col=None,
            start_s=float(times[a - 1] - origin), end_s=float(times[b] - origin),
            value=b - a + 1, unit="messages",
            sentence=(
                f"{b - a + 1} {subject} messages arrived together, the first "
                f"{burst.late_s * 1e3:.0f} ms late"
                + (f" ({more} more bursts like it)" if more > 0 else "")
                + "."
            ),
            action=burst_action,
        ))
    return out
