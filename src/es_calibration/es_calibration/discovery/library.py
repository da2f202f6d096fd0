"""The discovery's term library: the factors of es_physics.effects.discovered on sampled rows.

Signals (each (A, n) on the screening block's actuators and chosen rows): the command V, its
rate, the temperature (from the data's mean), its rate, the time since the start, the
modelled displacement, the 4-neighbour means of the command, of the temperature (minus the
actuator's own) and of its rate, first-order low-passes of V and V^2 at time constants
spread from ``LOWPASS_SHORTEST_PERIODS`` command periods to a fifth of the record, the
command delayed by ``DELAY_PERIODS`` periods, sin / cos of the displacement over the
interferometer's periods (``FRINGE_LENGTHS_M``), the magnitude of the command's rate, the
actuator's place in the whole grid (distance from the rim, x, y) and, where the model's
displacement at every command is given (:func:`displacement_series`), its logarithmic creep
(low-passes of it, one per decade from ``CREEP_SHORTEST_PERIODS`` command periods).

A term adds where its :class:`~es_physics.effects.discovered.Carrier` says: to the
displacement (every factor but the place and the fringes, alone and every product of two,
squares included; the creep alone), to the voltage in effect or to the
law's temperature (the factors of ``CARRIER_FACTORS``, alone and in pairs, times the model's
sensitivity dz/dV or dz/dT at the sample, so the coefficient is in V or degC), or to the
measurement (the fringes: a metrology error depends on what the interferometer sees,
nothing else). The scales are the recording's
own (each column is divided by its training RMS for the regression, and the coefficient
converted back).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Final

import numpy as np

from es_calibration.data.align import AlignedData
from es_calibration.discovery.terms import FactorKey
from es_calibration.model.history import lowpass_at
from es_common.arrays import BoolArray, FloatArray, IndexArray
from es_physics.effects.discovered import (
    CREEP,
    POSITION,
    Carrier,
    creep_time_constants,
    grid_position,
    neighbour_mean,
    rate_magnitude,
)

#: Low-pass time constants: this many command periods at the shortest ...
LOWPASS_SHORTEST_PERIODS: Final = 20.0
#: ... to this fraction of the record at the longest, log-spaced, ``LOWPASS_COUNT`` of them.
LOWPASS_LONGEST_FRACTION: Final = 0.2
LOWPASS_COUNT: Final = 6
#: Delays of the command tried, in command periods.
DELAY_PERIODS: Final = (1, 2, 5, 10)
#: Limits of the command's rate magnitude tried: these quantiles of its nonzero values.
RATE_LIMIT_QUANTILES: Final = (0.5, 0.8, 0.95)
#: Periods of an interferometer's periodic error: a HeNe laser's lambda/2 and lambda/4 [m].
FRINGE_LENGTHS_M: Final = (316.4e-9, 158.2e-9)
#: Factor codes of the fringes (sin and cos of the displacement over those periods).
FRINGES: Final = (13, 14)
#: The creep's shortest time constant tried, in command periods (then refined).
CREEP_SHORTEST_PERIODS: Final = (3.0, 10.0, 30.0)
#: Factor codes of the terms that add to the drive or to the law's temperature: what an
#: amplifier's output error follows (the command, its rate and the neighbours' commands) and
#: what a temperature the sensors miss follows (a sensor's gain, the temperatures' rates and
#: differences, the time, the place in the grid).
CARRIER_FACTORS: Final = {
    Carrier.DRIVE: (1, 2, 15, 7),  # 15: every limit tried
    Carrier.TEMPERATURE: (3, 4, 5, 8, 9, 16, 17, 18),
    Carrier.MEASUREMENT: FRINGES,
}
#: Keys of the model's sensitivities in :meth:`Library.signals`'s result (not factors).
SLOPE_KEYS: Final = {Carrier.DRIVE: (-1, 0.0), Carrier.TEMPERATURE: (-2, 0.0)}

#: A library term: where it adds and its factors.
LibraryTerm = tuple[Carrier, tuple[FactorKey, ...]]


def lowpass_taus(aligned: AlignedData) -> tuple[float, ...]:
    """Return the library's low-pass time constants [s] from the record's period and length."""
    shortest = LOWPASS_SHORTEST_PERIODS * aligned.command_period
    longest = max(LOWPASS_LONGEST_FRACTION * float(aligned.t[-1]), 2.0 * shortest)
    return tuple(float(v) for v in np.geomspace(shortest, longest, LOWPASS_COUNT))


@dataclass(frozen=True)
class Rows:
    """Where the library is evaluated: sample rows and what the model predicts there.

    Attributes:
        rows: sample rows (n,).
        prediction: the registry model's displacement (A, n) [m] (block actuators).
        residual: measured minus ``prediction`` (A, n) [m], NaN where not usable.
        drive_slope: the model's dz/dV there (A, n) [m/V].
        temperature_slope: the model's dz/dT there (A, n) [m/degC].

    """

    rows: IndexArray
    prediction: FloatArray
    residual: FloatArray
    drive_slope: FloatArray
    temperature_slope: FloatArray


class Library:
    """Factor signals of one block on sample rows, built once and combined into terms."""

    def __init__(self, aligned: AlignedData, grid: tuple[int, int],
                 taus: tuple[float, ...] | None = None,
                 placement: tuple[IndexArray, tuple[int, int]] | None = None,
                 displacement: FloatArray | None = None) -> None:
        """Keep the block's record (``aligned``, actuators row-major in ``grid``).

        ``placement``: the block's actuators as row-major indices of the whole grid, and
        that grid (default: the block is the grid). ``displacement``: the model's
        displacement at every command (Nc, A) [m] (:func:`displacement_series`) for the
        creep (None: no creep in the library).
        """
        self.aligned = aligned
        self._displacement = displacement
        self.grid = grid
        self.taus = lowpass_taus(aligned) if taus is None else taus
        self._command = np.nan_to_num(aligned.command)
        where, whole = placement or (np.arange(aligned.n_actuators, dtype=np.intp), grid)
        self._position = {c: grid_position(c, whole).ravel()[where] for c in POSITION}

    def keys(self) -> list[FactorKey]:
        """Return every single factor of the library, (code, parameter)."""
        a = self.aligned
        keys: list[FactorKey] = [
            (1, 0.0), (2, 0.0), (3, a.mean_temperature), (4, 0.0), (5, a.start_time),
            (6, 0.0), (7, 0.0), (8, 0.0), (9, 0.0), (15, 0.0),
        ]
        keys += [(15, limit) for limit in self.rate_limits()]
        keys += [(10, tau) for tau in self.taus] + [(11, tau) for tau in self.taus]
        if self._displacement is not None:
            keys += [(CREEP, periods * a.command_period) for periods in CREEP_SHORTEST_PERIODS]
        keys += [(12, j * a.command_period) for j in DELAY_PERIODS]
        keys += [(code, length) for length in FRINGE_LENGTHS_M for code in (13, 14)]
        keys += [(code, 0.0) for code in sorted(POSITION)]
        if a.n_actuators < 2:  # the neighbours of a single actuator are itself; no place
            keys = [k for k in keys if k[0] not in (7, 8, 9, *POSITION)]
        return keys

    def rate_limits(self) -> tuple[float, ...]:
        """Return the limits [V/s] of |dV/dt| tried: ``RATE_LIMIT_QUANTILES`` of the record's."""
        rate = np.abs(np.diff(self._command, axis=0)) / self.aligned.command_period
        moving = rate[rate > 0]
        if moving.size == 0:
            return ()
        return tuple(float(q) for q in np.unique(np.quantile(moving, RATE_LIMIT_QUANTILES)))

    def terms(self, singles: list[FactorKey]) -> list[LibraryTerm]:
        """Return every term of the library (see the module docstring) from its ``singles``."""
        out: list[LibraryTerm] = [
            (Carrier.DISPLACEMENT, t)
            for t in product_keys([k for k in singles
                                   if k[0] not in (*POSITION, *FRINGES, CREEP)])
        ]
        out += [(Carrier.DISPLACEMENT, (k,)) for k in singles if k[0] == CREEP]
        for carrier, codes in CARRIER_FACTORS.items():
            own = [k for k in singles if k[0] in codes]
            out += [(carrier, t) for t in product_keys(own)]
        return out

    @cached_property
    def _squared(self) -> FloatArray:
        """The command squared, V^2 (Nc, A)."""
        return np.asarray(self._command**2, np.float64)

    def _lowpass(self, key: FactorKey, rows: IndexArray) -> FloatArray:
        """Return LP_tau(V), LP_tau(V^2) or the creep at command ``rows`` (len(rows), A).

        Only those rows are kept (one compiled pass where the kernels are fused, see
        :func:`~es_calibration.model.history.lowpass_at`): a full-rate series per time
        constant was about 1 s and 77 MB on an 8 x 8 block of 5 minutes at 500 Hz.
        """
        period = self.aligned.command_period
        if key[0] == CREEP:
            if self._displacement is None:
                raise KeyError("the creep without the model's displacement")
            z = self._displacement[rows]
            return np.asarray(sum(lowpass_at(self._displacement, period, float(tau), rows,
                                             with_slope=False)[0] - z
                                  for tau in creep_time_constants(key[1])), np.float64)
        x = self._command if key[0] == 10 else self._squared
        return lowpass_at(x, period, key[1], rows, with_slope=False)[0]

    def _grid_mean(self, x: FloatArray) -> FloatArray:
        """Return the 4-neighbour mean of (A, n) values on the block's grid."""
        n = x.shape[1]
        cube = x.T.reshape(n, *self.grid)
        return np.asarray(neighbour_mean(cube).reshape(n, -1).T, np.float64)

    def signals(self, at: Rows, keys: list[FactorKey]) -> dict[FactorKey, FloatArray]:
        """Return each factor's values (A, n) at ``at.rows``.

        Raises:
            KeyError: a factor code the library does not know.

        """
        a = self.aligned
        rows = at.rows
        act = np.arange(a.n_actuators)
        ci = np.maximum(a.command_index(rows, 0.0), 0)
        V = self._command[ci].T
        T = a.temperature_at(rows, act)
        rate = a.temperature_rate_at(rows, act)
        needed, where = np.unique(ci, return_inverse=True)  # the low-passes' command rows
        out: dict[FactorKey, FloatArray] = {
            SLOPE_KEYS[Carrier.DRIVE]: at.drive_slope,
            SLOPE_KEYS[Carrier.TEMPERATURE]: at.temperature_slope,
        }
        for key in keys:
            code, p = key
            if code == 1:
                out[key] = V
            elif code in (2, 15):
                dv = (V - self._command[np.maximum(ci - 1, 0)].T) / a.command_period
                out[key] = dv if code == 2 else rate_magnitude(dv, p)
            elif code == 3:
                out[key] = T - p
            elif code == 4:
                out[key] = rate
            elif code == 5:
                out[key] = np.broadcast_to(a.t[rows], V.shape)
            elif code == 6:
                out[key] = at.prediction
            elif code == 7:
                out[key] = self._grid_mean(V)
            elif code == 8:
                out[key] = self._grid_mean(T) - T
            elif code == 9:
                out[key] = self._grid_mean(rate)
            elif code in (10, 11, CREEP):
                out[key] = self._lowpass(key, needed)[where].T
            elif code == 12:
                shift = round(p / a.command_period)
                out[key] = self._command[np.maximum(ci - shift, 0)].T
            elif code in (13, 14):
                phase = 2.0 * np.pi * at.prediction / p
                out[key] = np.sin(phase) if code == 13 else np.cos(phase)
            elif code in POSITION:
                out[key] = np.broadcast_to(self._position[code][:, None], V.shape)
            else:
                raise KeyError(f"no library factor with code {code}")
        return out


def displacement_series(aligned: AlignedData, rows: IndexArray, values: FloatArray
                        ) -> FloatArray:
    """Return ``values`` (A, n) at displacement ``rows`` as a series at every command (Nc, A).

    Each command takes the value of the last sample while it was in effect; a command with
    none (a dropped sample, an excluded row) keeps the one before (the first ones, the first
    value): a low-pass of it then sees the displacement held, as the strain is.
    """
    order = np.argsort(rows, kind="stable")
    index = np.maximum(aligned.command_index(np.asarray(rows)[order], 0.0), 0)
    held = np.asarray(values, np.float64)[:, order].T
    finite = np.all(np.isfinite(held), axis=1)
    index, held = index[finite], held[finite]
    n_commands = aligned.command.shape[0]
    if index.size == 0:
        return np.zeros((n_commands, aligned.n_actuators))
    last = np.full(n_commands, -1, np.intp)
    np.maximum.at(last, index, np.arange(index.size))  # the latest sample of a command wins
    filled = np.maximum.accumulate(last)
    return np.asarray(held[np.where(filled >= 0, filled, 0)], np.float64)


def product_keys(singles: list[FactorKey]) -> list[tuple[FactorKey, ...]]:
    """Return every term of the library: each single factor, then each product of two."""
    terms: list[tuple[FactorKey, ...]] = [(k,) for k in singles]
    terms += [
        (singles[i], singles[j]) for i in range(len(singles)) for j in range(i, len(singles))
    ]
    return terms


def columns(signals: dict[FactorKey, FloatArray], terms: list[LibraryTerm],
            pick: tuple[IndexArray, IndexArray]) -> FloatArray:
    """Return the terms' displacements (m, len(terms)) [m] at the (actuator, row) ``pick``.

    A drive or temperature term's product is taken through the model's sensitivity.
    """
    flat = {k: v[pick] for k, v in signals.items()}
    out = np.empty((pick[0].size, len(terms)))
    for j, (carrier, factors) in enumerate(terms):
        value = flat[factors[0]]
        if len(factors) > 1:
            value = value * flat[factors[1]]
        if carrier in SLOPE_KEYS:  # the displacement and the measurement take it as it is
            value = value * flat[SLOPE_KEYS[carrier]]
        out[:, j] = value
    return out


def usable(residual: FloatArray, signals: dict[FactorKey, FloatArray]) -> BoolArray:
    """Return where the residual and every signal are finite (A, n)."""
    ok = np.isfinite(residual)
    for v in signals.values():
        ok &= np.isfinite(v)
    return ok
