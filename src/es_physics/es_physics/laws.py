"""Forward and inverse electrostrictive models, vectorised over any array shape.

Equations: ``shared/docs/physics.md`` (thesis typos corrected). Every inverse returns the
voltage together with a per-element :class:`Status`, so that a caller can turn what happened
to each actuator into diagnostics; no inverse ever returns NaN or a voltage beyond ``v_limit``.

Two layers: the functions (``hyperbolic_inverse(z, T, params)``, ...) take temperatures and
parameters directly; :class:`CompiledLaws` and :class:`LawsAtTemperature` split the work so
that a feedforward loop evaluates the temperature laws once per temperature update and pays
only a few array operations per set point (see ``bench/bench_kernels.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntEnum
from functools import cached_property
from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt

from es_common.arrays import BoolArray
from es_physics.params import (
    VALIDITY_MARGIN_BELOW_TM,
    VALIDITY_SPAN_ABOVE_TM,
    ActuatorParams,
    FloatArray,
)

#: Amplifier limit of the thesis set-up [V].
DEFAULT_V_LIMIT: Final = 350.0
#: u* = atanh(1/sqrt(3)): where the slope dz/dV of the hyperbolic model peaks.
U_STAR: Final = float(np.arctanh(1.0 / np.sqrt(3.0)))
#: Largest z / z_sat handed to atanh(sqrt(.)): keeps the result finite (u <= ~14.5).
RATIO_CAP: Final = 1.0 - 1e-12

StatusArray = npt.NDArray[np.int8]


class Status(IntEnum):
    """Per-element outcome of a model evaluation, ordered by severity."""

    OK = 0
    OUT_OF_VALIDITY = 1  # temperature outside the laws' range: evaluated at the nearest bound
    CLIPPED_LOW = 2  # set point below 0: driven to 0 V
    CLIPPED_HIGH = 3  # set point beyond what v_limit reaches (or z_sat): driven to the limit
    INVALID = 4  # non-finite input or parameters: 0 V


# Plain-int codes for array work: comparing a numpy scalar with an IntEnum member costs ~6 us.
CODE_OK: Final = int(Status.OK)
CODE_OUT_OF_VALIDITY: Final = int(Status.OUT_OF_VALIDITY)
CODE_CLIPPED_LOW: Final = int(Status.CLIPPED_LOW)
CODE_CLIPPED_HIGH: Final = int(Status.CLIPPED_HIGH)
CODE_INVALID: Final = int(Status.INVALID)


class InverseResult(NamedTuple):
    """Voltages [V] and per-element :class:`Status` codes (int8) of an inverse model.

    ``worst`` is the largest code of ``status`` when the producer counted it on the way (a
    compiled pass does), else ``None``: the caller then takes ``status.max()`` if it needs it.
    A named tuple: a feedforward builds one per set point.
    """

    voltage: FloatArray
    status: StatusArray
    worst: int | None = None


def z_sat(T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return the saturation displacement M L / k^2 [m] of the hyperbolic model."""
    k = params.k(T)
    return np.asarray(params.M(T) * params.L / (k * k), np.float64)


def d_max(T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return the largest slope dz/dV = 4 M / (3 sqrt(3) k) [m/V] of the hyperbolic model."""
    return np.asarray(4.0 * params.M(T) / (3.0 * np.sqrt(3.0) * params.k(T)), np.float64)


def v_max(T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return the voltage u* L / k [V] at which the slope peaks (displacement z_sat / 3 there)."""
    return np.asarray(U_STAR * params.L / params.k(T), np.float64)


def hyperbolic_forward(V: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return z = (M L / k^2) tanh^2(k V / L) [m] (even in V)."""
    k = params.k(T)
    t = np.tanh(k * np.asarray(V, np.float64) / params.L)
    return np.asarray(params.M(T) * params.L / (k * k) * t * t, np.float64)


def hyperbolic_slope(V: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return d(V) = dz/dV = (2 M / k) tanh(u) sech^2(u), u = k V / L [m/V]."""
    k = params.k(T)
    u = k * np.asarray(V, np.float64) / params.L
    t = np.tanh(u)
    return np.asarray(2.0 * params.M(T) / k * t * (1.0 - t * t), np.float64)


def quadratic_forward(V: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams) -> FloatArray:
    """Return z = M V^2 / L [m] (Mason's low-field model)."""
    V = np.asarray(V, np.float64)
    return np.asarray(params.M(T) * V * V / params.L, np.float64)


def _as_array(value: npt.ArrayLike, shape: tuple[int, ...]) -> FloatArray:
    return np.array(np.broadcast_to(np.asarray(value, np.float64), shape), np.float64)


class CompiledLaws:
    """Temperature laws of a parameter set, rearranged once for fast repeated evaluation.

    Holds k/L and M/L as polynomials in T* = T - Tm (per-actuator arrays of ``shape``, or
    scalars for ``shape == ()``), so that :meth:`at` costs a handful of array operations.
    """

    def __init__(self, params: ActuatorParams, shape: tuple[int, ...] = ()) -> None:
        self.params = params
        self.shape = shape
        L = _as_array(params.L, shape)
        self.Tm = _as_array(params.Tm, shape)
        # q(T*) = k / L [1/V] and n(T*) = M / L [m/V^2]: the only combinations the models use.
        self.q = tuple(_as_array(getattr(params, c), shape) / L for c in ("k2", "k1", "k3"))
        self.n = tuple(_as_array(getattr(params, c), shape) / L for c in ("m2", "m1", "m3"))
        self._q_curved = bool(np.any(self.q[2]))
        self._n_curved = bool(np.any(self.n[2]))
        # Laws that are positive over the whole validity range stay positive after clamping,
        # so only parameter sets failing this need a per-call check.
        self.usable = self.positive_between(VALIDITY_MARGIN_BELOW_TM, VALIDITY_SPAN_ABOVE_TM)
        self._safe_low, self._safe_high = self._common_positive_range()

    def _common_positive_range(self) -> tuple[float, float]:
        """Return the open T* interval in which every element's k and M are positive.

        Linear laws only (empty interval otherwise): calls whose temperatures all fall inside
        it skip the per-element positivity check.
        """
        empty = (np.inf, -np.inf)
        if self._q_curved or self._n_curved:
            return empty
        low, high = -np.inf, np.inf
        for law in (self.q, self.n):
            c0, c1 = np.broadcast_arrays(law[0], law[1])
            if not (np.all(np.isfinite(c0)) and np.all(np.isfinite(c1))):
                return empty
            if np.any((c1 == 0.0) & (c0 <= 0.0)):
                return empty
            falling, rising = c1 < 0.0, c1 > 0.0
            if np.any(falling):
                high = min(high, float(np.min(-c0[falling] / c1[falling])))
            if np.any(rising):
                low = max(low, float(np.max(-c0[rising] / c1[rising])))
        return (low, high) if np.all(np.isfinite(self.Tm)) else empty

    def positive_between(self, ts_low: float, ts_high: float) -> BoolArray:
        """Return, per element, whether k and M stay finite and > 0 for T* in [low, high]."""
        ok = np.ones(np.broadcast_shapes(self.Tm.shape, *(c.shape for c in self.q)), bool)
        for c0, c1, c2 in (self.q, self.n):
            # a quadratic's minimum over an interval is at an end or at its vertex
            with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
                vertex = np.where(c2 != 0.0, -c1 / (2.0 * c2), ts_low)
            vertex = np.clip(vertex, ts_low, ts_high)
            for ts in (ts_low, ts_high, vertex):
                value = c0 + ts * (c1 + ts * c2)
                ok &= np.isfinite(value) & (value > 0.0)
        return ok & np.isfinite(self.Tm)

    def at(self, T: npt.ArrayLike) -> LawsAtTemperature:
        """Evaluate the laws at temperatures ``T`` (clamped into the validity range).

        Elements whose law is not positive at their temperature get ``Status.INVALID`` and
        neutral coefficients (checked per element only when some temperature lies outside
        the interval in which every element's laws are positive).
        """
        T = np.asarray(T, np.float64)
        ts = np.asarray(T - self.Tm, np.float64)
        lo = ts.min() if ts.size else VALIDITY_MARGIN_BELOW_TM
        hi = ts.max() if ts.size else VALIDITY_MARGIN_BELOW_TM
        status: StatusArray
        if lo >= VALIDITY_MARGIN_BELOW_TM and hi <= VALIDITY_SPAN_ABOVE_TM:
            status = np.zeros(ts.shape, np.int8)
            flagged = False
        else:  # some temperatures are outside the laws' range or not finite (NaN fails both)
            finite = np.isfinite(ts)
            clamped = np.clip(
                np.where(finite, ts, VALIDITY_MARGIN_BELOW_TM + 10.0),
                VALIDITY_MARGIN_BELOW_TM,
                VALIDITY_SPAN_ABOVE_TM,
            )
            status = np.where(clamped != ts, CODE_OUT_OF_VALIDITY, CODE_OK).astype(np.int8)
            status[~finite] = CODE_INVALID
            ts = clamped
            flagged = True
        q = self.q[1] * ts
        q += self.q[0]
        n = self.n[1] * ts
        n += self.n[0]
        if self._q_curved:
            q += self.q[2] * ts * ts
        if self._n_curved:
            n += self.n[2] * ts * ts
        q, n = np.asarray(q, np.float64), np.asarray(n, np.float64)
        if flagged and ts.size:  # clamped: the range to check is that of the clamped values
            lo, hi = ts.min(), ts.max()
        if not (self._safe_low < lo and hi < self._safe_high):
            bad = ~((q > 0.0) & (n > 0.0) & np.isfinite(q) & np.isfinite(n))
            status[bad] = CODE_INVALID
            q = np.where(bad, 1.0, q)
            n = np.where(bad, 1.0, n)
            flagged = True
        inv_zsat = q * q
        inv_zsat /= n
        return LawsAtTemperature(
            q=q, n=n, inv_zsat=np.asarray(inv_zsat, np.float64), status=status, flagged=flagged
        )

    def hyperbolic_inverse(
        self, z: npt.ArrayLike, T: npt.ArrayLike, v_limit: float = DEFAULT_V_LIMIT
    ) -> InverseResult:
        """Return ``self.at(T).hyperbolic_inverse(z, v_limit)``, fused for speed.

        The common case (temperatures in range, set points in reach, usable laws) runs as a
        dozen in-place array operations; anything else falls back to the general path.
        """
        ts = np.subtract(T, self.Tm)
        # 0-d: numpy returns scalars, which the in-place steps below cannot use
        if not (np.ndim(ts) and ts.size):
            return self.at(T).hyperbolic_inverse(z, v_limit)
        lo, hi = ts.min(), ts.max()
        if not (
            lo >= VALIDITY_MARGIN_BELOW_TM
            and hi <= VALIDITY_SPAN_ABOVE_TM
            and self._safe_low < lo
            and hi < self._safe_high
        ):
            return self.at(T).hyperbolic_inverse(z, v_limit)
        q = np.multiply(self.q[1], ts)
        q += self.q[0]
        n = np.multiply(self.n[1], ts, out=ts)
        n += self.n[0]
        ratio = np.multiply(z, q)  # z / z_sat = z q^2 / n
        ratio *= q
        ratio /= n
        if not (ratio.min() >= 0.0 and ratio.max() < RATIO_CAP):  # NaN fails too
            return self.at(T).hyperbolic_inverse(z, v_limit)
        np.sqrt(ratio, out=ratio)
        np.arctanh(ratio, out=ratio)
        ratio /= q
        status = np.zeros(ratio.shape, np.int8)
        if ratio.max() < v_limit:
            return InverseResult(ratio, status)
        return limit_voltages(ratio, status, v_limit, flagged=False)


@dataclass(frozen=True)
class LawsAtTemperature:
    """The model coefficients at one set of temperatures.

    Attributes:
        q: k / L [1/V] (u = q V).
        n: M / L [m/V^2] (quadratic model z = n V^2).
        inv_zsat: 1 / z_sat = q^2 / n [1/m].
        status: per-element status of the temperatures (OK, OUT_OF_VALIDITY or INVALID).
        flagged: whether any element of ``status`` is not OK.

    """

    q: FloatArray
    n: FloatArray
    inv_zsat: FloatArray
    status: StatusArray
    flagged: bool = True

    # Derived coefficients are computed on first use and kept: a feedforward evaluates the
    # laws once per temperature update and uses them for every set point until the next.
    @cached_property
    def z_sat(self) -> FloatArray:
        """z_sat = M L / k^2 [m]."""
        return np.asarray(1.0 / self.inv_zsat, np.float64)

    @cached_property
    def d_max(self) -> FloatArray:
        """The largest slope 4 M / (3 sqrt(3) k) [m/V] of the hyperbolic model."""
        return np.asarray(4.0 / (3.0 * np.sqrt(3.0)) * self.n / self.q, np.float64)

    @cached_property
    def v_max(self) -> FloatArray:
        """The voltage u* L / k [V] of the largest slope."""
        return np.asarray(U_STAR / self.q, np.float64)

    @cached_property
    def linear_offset(self) -> FloatArray:
        """V_max - (z_sat / 3) / d_max [V]: V = linear_offset + z / d_max linearises at V_max."""
        return np.asarray(self.v_max - self.z_sat / 3.0 / self.d_max, np.float64)

    @cached_property
    def sqrt_n(self) -> FloatArray:
        """sqrt(M / L) [sqrt(m)/V]: the low-field gain of sqrt(z) over V."""
        return np.asarray(np.sqrt(self.n), np.float64)

    @cached_property
    def sqrt_z_sat(self) -> FloatArray:
        """sqrt(z_sat) [sqrt(m)]."""
        return np.asarray(np.sqrt(self.z_sat), np.float64)

    def hyperbolic_forward(self, V: npt.ArrayLike) -> FloatArray:
        """Return z = z_sat tanh^2(q V) [m]."""
        t = np.tanh(self.q * np.asarray(V, np.float64))
        return np.asarray(t * t / self.inv_zsat, np.float64)

    def hyperbolic_slope(self, V: npt.ArrayLike) -> FloatArray:
        """Return dz/dV = 2 z_sat q tanh(u) sech^2(u) [m/V]."""
        t = np.tanh(self.q * np.asarray(V, np.float64))
        return np.asarray(2.0 * self.q / self.inv_zsat * t * (1.0 - t * t), np.float64)

    def quadratic_forward(self, V: npt.ArrayLike) -> FloatArray:
        """Return z = M V^2 / L [m]."""
        V = np.asarray(V, np.float64)
        return np.asarray(self.n * V * V, np.float64)

    def hyperbolic_inverse(self, z: npt.ArrayLike, v_limit: float) -> InverseResult:
        """Return V = atanh(sqrt(z / z_sat)) / q with its status (rules of hyperbolic_inverse)."""
        ratio = np.multiply(z, self.inv_zsat, out=np.empty(self.q.shape))
        lo = ratio.min() if ratio.size else 0.0
        hi = ratio.max() if ratio.size else 0.0
        status = self.status.copy()
        beyond = None
        flagged = self.flagged
        if not (lo >= 0.0 and hi < RATIO_CAP):  # NaN fails too
            ratio, status, beyond = clean_inputs(ratio, status)
            flagged = True
        np.sqrt(ratio, out=ratio)
        np.arctanh(ratio, out=ratio)
        voltage = np.divide(ratio, self.q, out=ratio)
        if beyond is not None:
            voltage[beyond] = v_limit
        return limit_voltages(voltage, status, v_limit, flagged)

    def quadratic_inverse(self, z: npt.ArrayLike, v_limit: float) -> InverseResult:
        """Return V = sqrt(z / n) with its status (rules of quadratic_inverse)."""
        z = np.multiply(z, 1.0, out=np.empty(self.q.shape))
        status = self.status.copy()
        lo = z.min() if z.size else 0.0
        hi = z.max() if z.size else 0.0
        flagged = self.flagged
        if not (lo >= 0.0 and hi < np.inf):  # NaN fails too; the quadratic model has no z_sat
            z, status, _ = clean_inputs(z, status, cap=np.inf)
            flagged = True
        voltage = np.divide(z, self.n, out=z)
        np.sqrt(voltage, out=voltage)
        return limit_voltages(voltage, status, v_limit, flagged)


def clean_inputs(
    ratio: FloatArray, status: StatusArray, cap: float = RATIO_CAP
) -> tuple[FloatArray, StatusArray, BoolArray]:
    """Return (ratio with bad entries replaced by 0 or the cap, updated status, beyond-cap mask)."""
    invalid = ~np.isfinite(ratio) | (status == CODE_INVALID)
    negative = (ratio < 0.0) & ~invalid
    beyond = (ratio >= cap) & ~invalid
    status[negative] = np.maximum(status[negative], CODE_CLIPPED_LOW)
    status[beyond] = np.maximum(status[beyond], CODE_CLIPPED_HIGH)
    status[invalid] = CODE_INVALID
    cleaned = np.asarray(np.where(invalid | negative | beyond, 0.0, ratio), np.float64)
    return cleaned, status, beyond


def limit_voltages(
    voltage: FloatArray, status: StatusArray, v_limit: float, flagged: bool = True
) -> InverseResult:
    """Clip voltages to [0, v_limit], mark CLIPPED_HIGH, force 0 V for low/invalid elements.

    ``flagged`` False promises that ``status`` is all OK so far (skips a scan).
    """
    if voltage.size and not voltage.max() < v_limit:  # NaN or over the limit
        over = ~(voltage < v_limit)
        # status = max(status, CLIPPED_HIGH) where over; masked copies beat boolean indexing
        np.maximum(status, over.view(np.int8) * np.int8(CODE_CLIPPED_HIGH), out=status)
        np.copyto(voltage, v_limit, where=over)
    if flagged and status.size and status.max() >= CODE_CLIPPED_LOW:
        np.copyto(voltage, 0.0, where=(status == CODE_CLIPPED_LOW) | (status == CODE_INVALID))
    return InverseResult(voltage, status)


def broadcast_shape(params: ActuatorParams, *values: npt.ArrayLike) -> tuple[int, ...]:
    """Return the shape that ``values`` and every parameter field broadcast to."""
    shapes = [np.shape(v) for v in values]
    shapes += [np.shape(getattr(params, f.name)) for f in fields(params)]
    return np.broadcast_shapes(*shapes)


def laws_at(T: npt.ArrayLike, params: ActuatorParams, shape: tuple[int, ...]) -> LawsAtTemperature:
    """Return the coefficients at temperatures ``T`` broadcast to ``shape``."""
    return CompiledLaws(params, shape).at(np.broadcast_to(np.asarray(T, np.float64), shape))


def hyperbolic_inverse(
    z: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams, v_limit: float = DEFAULT_V_LIMIT
) -> InverseResult:
    """Return V = (L / k) atanh(sqrt(z / z_sat)) with its status.

    Set points at or beyond z(v_limit, T) (which is below z_sat) give ``v_limit`` and
    ``CLIPPED_HIGH``; negative ones 0 V and ``CLIPPED_LOW``; non-finite inputs 0 V and
    ``INVALID``; temperatures outside the laws' range are clamped to it (``OUT_OF_VALIDITY``).
    """
    z = np.asarray(z, np.float64)
    shape = broadcast_shape(params, z, T)
    T = np.broadcast_to(np.asarray(T, np.float64), shape)
    return CompiledLaws(params, shape).hyperbolic_inverse(np.broadcast_to(z, shape), T, v_limit)


def quadratic_inverse(
    z: npt.ArrayLike, T: npt.ArrayLike, params: ActuatorParams, v_limit: float = DEFAULT_V_LIMIT
) -> InverseResult:
    """Return V = sqrt(z L / M) with its status (same clipping rules as the hyperbolic inverse)."""
    z = np.asarray(z, np.float64)
    shape = broadcast_shape(params, z, T)
    return laws_at(T, params, shape).quadratic_inverse(np.broadcast_to(z, shape), v_limit)
