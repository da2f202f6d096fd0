"""The command-to-displacement delay measured block by block over the record (timing health).

Before any effect is searched, the plain law (linear in T*) is fitted at the shift that
fits best (whole command periods, then ``FINE_STEP`` fractions, the command interpolated as
search/state.py does) on up to ``ACTUATORS`` actuators of the screening block and rows
spread over the whole record. With that law fixed, each of ``BLOCKS`` consecutive time blocks
gets the shift that fits its own rows best (a coarse scan, a fine one, a parabola through
the best three). Unlike the model's shift (search/state.py), which counts periods from the
command in effect at a sample's stamp and so cannot see a stamp moving within a period, the
shift here is continuous time: the command is interpolated (the same cubic kernel) at the
instant t - d itself, so a displacement clock drifting against the command's shows. A
straight line through the blocks' shifts is a clock-rate difference
between the command's and the displacement's loggers (data/timing.py).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Final

import numpy as np

from es_calibration.data.align import AlignedData
from es_calibration.data.delayrange import longest_whole_shift
from es_calibration.model.cache import BoundedCache, rows_key
from es_calibration.model.composite import CompositeModel, FitInputs
from es_calibration.model.fit import levenberg_marquardt
from es_calibration.search.scans import lowest_shift
from es_calibration.search.state import Workspace, initial_law
from es_common.arrays import FloatArray, IndexArray
from es_feedforward.kernels import Backend, default_backend

#: Time blocks whose delays are measured.
BLOCKS: Final = 16
#: Rows per block at most, and actuators used.
BLOCK_ROWS: Final = 1500
ACTUATORS: Final = 16
#: Fastest clock-rate difference the per-block scans reach [ppm] (a crystal is within 100).
MAX_PPM: Final = 300.0
#: Periods a block's scan reaches beyond its clock-rate span.
REACH_MARGIN: Final = 1.0
#: Steps of the coarse and the fine scans [command periods].
COARSE_STEP: Final = 0.25
FINE_STEP: Final = 0.05


class _Scan:
    """The plain law on fixed rows of a few actuators, and its cost at a command shift."""

    def __init__(self, aligned: AlignedData) -> None:
        a = min(ACTUATORS, aligned.n_actuators)
        self.ws = Workspace(aligned, np.arange(a, dtype=np.intp), (1, a))
        self.model = CompositeModel(())
        self.period = aligned.command_period
        self.law: FloatArray | None = None
        # candidate-independent: the actuators' command and the unshifted inputs per row set
        # (every scan step used to copy the whole command: 0.04 s a step, 6000 steps)
        self.command = np.ascontiguousarray(aligned.command[:, self.ws.actuators])
        self._base: BoundedCache[FitInputs] = BoundedCache(max_entries=2 * BLOCKS)

    def inputs(self, rows: IndexArray, shift: float) -> FitInputs:
        """Return the inputs at ``rows`` with the command at the instants ``shift`` earlier.

        The cubic convolution kernel (Keys, a = -1/2) over the four commands around each
        instant t - shift periods; samples whose taps are missing or span a gap are left out.
        """
        base = self._base.get(rows_key(rows))
        if base is None:
            base = self._base.put(rows_key(rows), self.ws.inputs(rows, 0.0, None))
        a = self.ws.aligned
        times = a.command_times
        when = a.t[rows] - shift * self.period
        j = np.searchsorted(times, when, side="right") - 1
        inside = (j >= 1) & (j + 2 < times.size)
        j = np.clip(j, 1, max(times.size - 3, 1))
        regular = np.abs(times[j + 2] - times[j - 1] - 3.0 * self.period) < 0.5 * self.period
        f = np.clip((when - times[j]) / self.period, 0.0, 1.0)
        weights = (
            (-(f**3) + 2 * f**2 - f) / 2,
            (3 * f**3 - 5 * f**2 + 2) / 2,
            (-3 * f**3 + 4 * f**2 + f) / 2,
            (f**3 - f**2) / 2,
        )
        if default_backend() is Backend.FUSED and times.size >= 4:  # else: numpy's IndexError
            from es_calibration.search.interp_loop import interpolate_rows

            voltage = np.empty((self.command.shape[1], rows.size))
            interpolate_rows(self.command, j - 1, np.stack(weights), voltage)
        else:
            voltage = np.asarray(
                sum(w[:, None] * self.command[j + k - 1] for k, w in enumerate(weights)),
                np.float64,
            ).T
        usable = base.valid & (inside & regular)[None, :]
        return replace(base, voltage=voltage, valid=usable,
                       displacement=np.where(usable, base.displacement, 0.0))

    def fit(self, rows: IndexArray, shift: float) -> None:
        """Fit the plain law on ``rows`` with the command ``shift`` periods earlier."""
        inputs = self.inputs(rows, shift)
        start = initial_law(inputs) if self.law is None else self.law
        self.law = levenberg_marquardt(
            lambda loc, glo, jac: self.model.evaluate(loc, glo, inputs, jac),
            inputs.displacement, inputs.valid, start, np.zeros(0), max_iter=20,
        ).local

    def cost(self, rows: IndexArray, shift: float) -> float:
        """Return the mean squared residual of the fixed law on ``rows`` at ``shift``."""
        assert self.law is not None  # fitted first
        inputs = self.inputs(rows, shift)
        pred = self.model.evaluate(self.law, np.zeros(0), inputs, jacobian=False).prediction
        resid = np.where(inputs.valid, inputs.displacement - pred, 0.0)
        return float(np.sum(resid * resid) / max(int(inputs.valid.sum()), 1))

    def best(self, rows: IndexArray, shifts: FloatArray) -> tuple[float, int, FloatArray]:
        """Return the best of ``shifts``, its position and every cost."""
        costs = np.array([self.cost(rows, float(s)) for s in shifts])
        i = int(np.nanargmin(costs))
        return float(shifts[i]), i, costs


def _refined(scan: _Scan, rows: IndexArray, centre: float, half: float) -> tuple[float, float]:
    """Return the best shift within ``half`` of ``centre`` [periods] and its variance.

    The best of a ``FINE_STEP`` scan, refined by a parabola through it and its neighbours;
    the variance [periods^2] is the least-squares one, 2 c0 / (n c''), of a minimum c0 of
    the mean squared residual with curvature c'' over n pairs (inf: no curvature).
    """
    shifts = centre + np.arange(-half, half + 0.5 * FINE_STEP, FINE_STEP)
    best, i, costs = scan.best(rows, shifts)
    variance = np.inf
    if 0 < i < shifts.size - 1:
        lo, mid, hi = costs[i - 1 : i + 2]
        curve = lo - 2.0 * mid + hi
        if curve > 0:
            best += FINE_STEP * 0.5 * (lo - hi) / curve
            pairs = rows.size * scan.ws.actuators.size
            variance = 2.0 * mid / (pairs * curve / FINE_STEP**2)
    return best, variance


def _block_reach(edges: FloatArray, period: float) -> FloatArray:
    """Return how far each block's shift can stray from the whole record's [periods] (B,).

    ``MAX_PPM`` over the block's farthest edge's distance from the record's middle, plus
    ``REACH_MARGIN`` (the whole record's shift is fitted, not exactly the middle's).
    """
    middle = 0.5 * (edges[0] + edges[-1])
    farthest = np.maximum(np.abs(edges[:-1] - middle), np.abs(edges[1:] - middle))
    return REACH_MARGIN + MAX_PPM * 1e-6 * farthest / period


def block_delays(aligned: AlignedData) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return the blocks' centre times, the delay measured in each and its sd (B,) [s].

    ``aligned`` is the screening block's alignment. A block with too few rows gets NaN.
    """
    scan = _Scan(aligned)
    t = aligned.t
    duration = float(t[-1])
    edges = np.linspace(0.0, duration, BLOCKS + 1)
    block = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, BLOCKS - 1)
    per_block: list[IndexArray] = []
    for b in range(BLOCKS):  # a few blocks; each row set lives as long as the scan's cache
        rows = np.flatnonzero(block == b)
        per_block.append(rows[:: max(1, int(np.ceil(rows.size / BLOCK_ROWS)))])
    every = np.concatenate(per_block)
    # the whole record's shift: plain law at none, whole periods, then fractions
    scan.fit(every, 0.0)
    lowest = np.ceil(lowest_shift(scan.ws))
    whole, _, _ = scan.best(every, np.arange(lowest, longest_whole_shift(scan.period) + 1.0))
    scan.fit(every, whole)
    shift, _ = _refined(scan, every, whole, 1.0)
    scan.fit(every, shift)
    # each block's own shift, the law fixed; the whole record's shift is that of its middle,
    # so a block strays from it by at most MAX_PPM times its farthest edge's distance from
    # the middle (a scan of the whole record's span per block was 4x the work)
    reach = _block_reach(edges, scan.period)
    delays = np.full(BLOCKS, np.nan)
    sigmas = np.full(BLOCKS, np.inf)
    for b, rows in enumerate(per_block):
        if rows.size < 50:
            continue
        coarse = shift + np.arange(-reach[b], reach[b] + 0.5 * COARSE_STEP, COARSE_STEP)
        near, _, _ = scan.best(rows, coarse)
        best, variance = _refined(scan, rows, near, COARSE_STEP)
        delays[b] = best * scan.period
        sigmas[b] = np.sqrt(variance) * scan.period
    return 0.5 * (edges[:-1] + edges[1:]), delays, sigmas
