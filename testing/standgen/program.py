"""The stand's drive: a voltage program defined at every instant, and the Peltier's profile.

The signal generator's program is a continuous-time function, so the actuator's drive can be
evaluated exactly at any instant, e.g. ``t - delay`` for a delay of a fraction of a command
period; the recorded /dm/command holds its samples at the command stamps. Segments of
0.8-2 s follow one another (sines 0.1-100 Hz, two tones, DC steps, ramps, DC + AC), joined by
raised-cosine edges of :data:`EDGE_S` (the amplifier's slew), and clipped to the amplifier's
+-:data:`V_LIMIT`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from standgen._typing import FloatArray
from standgen.operators import first_order_lag

#: Amplifier limit [V].
V_LIMIT: Final = 350.0
#: Duration of the raised-cosine edge between segments [s].
EDGE_S: Final = 2e-3
#: Segment kinds.
KINDS: Final = ("sine", "two_tone", "dc", "ramp", "dc_ac")
#: Largest amplitude [V] and its frequency scaling: A <= min(A_MAX, A_MAX * F_KNEE / f).
A_MAX: Final = 250.0
F_KNEE: Final = 5.0


@dataclass(frozen=True)
class Segment:
    """One program segment on [start, end) [s], evaluated per actuator.

    ``bias``, ``amplitudes`` (n tones) and ``phases`` are (R, C) maps (amplitudes and phases
    as (n, R, C)); ``frequencies`` [Hz] (n,); ``ramp_to`` the end level of a ramp (R, C).
    """

    kind: str
    start: float
    end: float
    bias: FloatArray
    frequencies: tuple[float, ...]
    amplitudes: FloatArray
    phases: FloatArray
    ramp_to: FloatArray | None = None

    def value(self, t: FloatArray) -> FloatArray:
        """Voltage (N, R, C) at times ``t`` (N,) [s] (meaningful inside the segment)."""
        tt = (t - self.start)[:, None, None]
        v = np.broadcast_to(self.bias, (t.size, *self.bias.shape)).copy()
        if self.ramp_to is not None:
            v += (self.ramp_to - self.bias) * (tt / (self.end - self.start))
        for f, a, p in zip(self.frequencies, self.amplitudes, self.phases, strict=True):
            v += a * np.sin(2 * np.pi * f * tt + p)
        return v


def _edge(x: FloatArray) -> FloatArray:
    """Raised-cosine step: 0 for x <= 0, 1 for x >= 1."""
    c = np.clip(x, 0.0, 1.0)
    return np.asarray(0.5 - 0.5 * np.cos(np.pi * c), np.float64)


@dataclass(frozen=True)
class VoltageProgram:
    """A sequence of segments covering [0, duration]; see the module docstring."""

    segments: tuple[Segment, ...]

    def __call__(self, t: npt.ArrayLike) -> FloatArray:
        """Voltage (N, R, C) [V] at times ``t`` (N,) [s]; before 0 the first segment holds."""
        ts = np.atleast_1d(np.asarray(t, np.float64))
        shape = self.segments[0].bias.shape
        out = np.zeros((ts.size, *shape))
        for i, seg in enumerate(self.segments):
            rise = np.ones_like(ts) if i == 0 else _edge((ts - seg.start) / EDGE_S)
            fall = (np.zeros_like(ts) if i == len(self.segments) - 1
                    else _edge((ts - seg.end) / EDGE_S))
            weight = rise - fall
            inside = weight > 0
            if np.any(inside):
                out[inside] += weight[inside, None, None] * seg.value(ts[inside])
        return np.clip(out, -V_LIMIT, V_LIMIT)


def make_program(rng: np.random.Generator, duration_s: float, shape: tuple[int, int],
                 rate_hz: float) -> VoltageProgram:
    """Draw a program of random segments for a grid ``shape`` sampled at ``rate_hz``.

    Tone frequencies are log-uniform in 0.1-100 Hz, at most a tenth of ``rate_hz``; each
    actuator gets its own phase and a 0.8-1.2 amplitude scale, so neighbours differ.
    """
    f_high = min(100.0, rate_hz / 10.0)
    segments: list[Segment] = []
    start = 0.0
    while start < duration_s:
        length = float(rng.uniform(0.8, 2.0))
        kind = str(rng.choice(KINDS))
        scale = rng.uniform(0.8, 1.2, shape)
        tones = {"sine": 1, "two_tone": 2, "dc_ac": 1}.get(kind, 0)
        freqs = tuple(float(np.exp(rng.uniform(np.log(0.1), np.log(f_high))))
                      for _ in range(tones))
        amps = np.array([rng.uniform(0.2, 1.0) * min(A_MAX, A_MAX * F_KNEE / f) / tones
                         for f in freqs]).reshape(tones, 1, 1) * scale
        phases = rng.uniform(0, 2 * np.pi, (tones, *shape))
        bias_level = {"sine": rng.uniform(0.0, 120.0), "two_tone": rng.uniform(0.0, 150.0),
                      "dc": rng.uniform(-100.0, 300.0), "ramp": rng.uniform(-150.0, 300.0),
                      "dc_ac": rng.uniform(100.0, 250.0)}[kind]
        bias = bias_level * scale
        ramp_to = rng.uniform(-150.0, 300.0) * scale if kind == "ramp" else None
        segments.append(Segment(kind, start, start + length, bias, freqs, amps, phases,
                                ramp_to))
        start += length
    return VoltageProgram(tuple(segments))


@dataclass(frozen=True)
class IndependentProgram:
    """One program per actuator (row-major ``programs`` of 1 x 1 each): edges at other times.

    The drive real mirrors are characterised with: every actuator its own segments, so an
    edge on one actuator falls in the middle of its neighbours' segments.
    """

    programs: tuple[VoltageProgram, ...]
    shape: tuple[int, int]

    def __call__(self, t: npt.ArrayLike) -> FloatArray:
        """Voltage (N, R, C) [V] at times ``t`` (N,) [s]."""
        columns = [p(t)[:, 0, 0] for p in self.programs]
        return np.stack(columns, axis=1).reshape(-1, *self.shape)


def make_independent_program(rng: np.random.Generator, duration_s: float,
                             shape: tuple[int, int], rate_hz: float) -> IndependentProgram:
    """Draw an independent program (:func:`make_program` on 1 x 1) for every actuator."""
    count = shape[0] * shape[1]
    return IndependentProgram(tuple(make_program(rng, duration_s, (1, 1), rate_hz)
                                    for _ in range(count)), shape)


@dataclass(frozen=True)
class PeltierProfile:
    """Base temperature: ramp low -> high, hold, ramp back down; smoothed by the Peltier's lag.

    ``rise`` and ``hold_until`` are fractions of the run (up until ``rise``, held until
    ``hold_until``, down at the end); ``lag_fraction`` of the run is the Peltier's first-order
    time constant.
    """

    duration_s: float
    low_degc: float = 40.0
    high_degc: float = 52.0
    rise: float = 0.4
    hold_until: float = 0.6
    lag_fraction: float = 0.03

    def __call__(self, t: FloatArray, dt: float) -> FloatArray:
        """Return the base temperature (N,) [degC] at uniform times ``t`` (N,) spaced ``dt`` [s]."""
        d = self.duration_s
        knots_t = [0.0, self.rise * d, self.hold_until * d, d]
        knots_v = [self.low_degc, self.high_degc, self.high_degc, self.low_degc]
        target = np.interp(t, knots_t, knots_v)
        return first_order_lag(target, dt, self.lag_fraction * d)
