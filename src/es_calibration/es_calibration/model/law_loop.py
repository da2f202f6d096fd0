"""The hyperbolic law, its slopes and its Jacobian columns in compiled passes (numba).

:meth:`es_calibration.model.composite.CompositeModel.evaluate` spent most of its time on
the law over (A, n) arrays: about twenty full-size numpy temporaries a call (M, k, tanh,
H, the slopes, the column products) and strided writes of each column into the (A, n, P)
Jacobian (37 of the 105 s of a 32 x 32 x 5 min calibration). Here one pass computes the
tanh argument and, after numpy's ``tanh`` (kept outside, so its last-bit result is the
same on both paths), a second pass computes everything else per sample. Both do the same
IEEE operations in the same order as the numpy path (no fused multiply-add, IEEE division),
so both give the same numbers (tests/es_calibration/test_caches.py).

Imported only where the kernels are ``fused`` (:func:`es_feedforward.kernels.default_backend`),
as :mod:`es_calibration.model.lowpass_loop`.
"""

from __future__ import annotations

import numba
import numpy as np

from es_common.arrays import FloatArray


@numba.njit(cache=True, nogil=True, error_model="numpy")
def law_argument(  # noqa: PLR0917 (numba calls are positional)
    temperature: FloatArray, voltage: FloatArray, local: FloatArray,
    curved: bool, length: float, out: FloatArray,
) -> None:
    """Write k(T*) V / L of (A, n) ``temperature`` T* and ``voltage`` into ``out``.

    ``local`` (A, >= 4) holds [m2, m1, k2, k1] (+ [m3, k3] when ``curved``).
    """
    rows, samples = temperature.shape
    for a in range(rows):
        k2 = local[a, 2]
        k1 = local[a, 3]
        k3 = local[a, 5] if curved else 0.0
        for i in range(samples):
            ts = temperature[a, i]
            k = k2 + ts * (k1 + ts * k3)
            out[a, i] = k * voltage[a, i] / length


@numba.njit(cache=True, nogil=True, error_model="numpy")
def law_terms(  # noqa: PLR0917 (numba calls are positional)
    temperature: FloatArray,
    voltage: FloatArray,
    th: FloatArray,
    local: FloatArray,
    curved: bool,
    length: float,
    jacobian: bool,
    with_temperature: bool,
    voltage_by_temperature: FloatArray,
    with_voltage_by_temperature: bool,
    law: FloatArray,
    by_voltage: FloatArray,
    by_temperature: FloatArray,
    columns: FloatArray,
) -> None:
    """Write the law H, dH/dV, dH/dT* and the law's Jacobian columns (unscaled).

    ``th`` is tanh(k V / L) (:func:`law_argument`, then numpy's tanh). ``columns`` is the
    (A, n, >= 4 or 6) Jacobian whose first columns take dH/d[m2, m1, k2, k1 (, m3, k3)];
    ``by_temperature`` gets dH/dT* + dH/dV ``voltage_by_temperature`` (the latter only
    ``with_voltage_by_temperature``). Without ``jacobian`` only ``law`` is written, without
    ``with_temperature`` not ``by_temperature``.
    """
    rows, samples = temperature.shape
    for a in range(rows):
        m2 = local[a, 0]
        m1 = local[a, 1]
        k2 = local[a, 2]
        k1 = local[a, 3]
        m3 = local[a, 4] if curved else 0.0
        k3 = local[a, 5] if curved else 0.0
        m3_twice = 2.0 * m3
        k3_twice = 2.0 * k3
        for i in range(samples):
            ts = temperature[a, i]
            t = th[a, i]
            m = m2 + ts * (m1 + ts * m3)
            k = k2 + ts * (k1 + ts * k3)
            by_m = length / (k * k) * t * t
            h = m * by_m
            law[a, i] = h
            if not jacobian:
                continue
            slope_part = m * t * (1.0 - t * t) / k
            by_k = (voltage[a, i] * slope_part - h) * (2.0 / k)
            by_v = 2.0 * slope_part
            by_voltage[a, i] = by_v
            columns[a, i, 0] = by_m
            columns[a, i, 1] = by_m * ts
            columns[a, i, 2] = by_k
            columns[a, i, 3] = by_k * ts
            if curved:
                columns[a, i, 4] = by_m * ts * ts
                columns[a, i, 5] = by_k * ts * ts
            if with_temperature:
                by_t = by_m * (m1 + m3_twice * ts) + by_k * (k1 + k3_twice * ts)
                if with_voltage_by_temperature:
                    by_t = by_t + by_v * voltage_by_temperature[a, i]
                by_temperature[a, i] = by_t


def fused_law(
    temperature: FloatArray,
    voltage: FloatArray,
    local: FloatArray,
    *,
    curved: bool,
    length: float,
    jacobian: bool,
    with_temperature: bool,
    voltage_by_temperature: FloatArray | None,
    columns: FloatArray,
    th: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Return H, dH/dV, dH/dT* and tanh(k V / L) (A, n); fill ``columns`` (see law_terms).

    dH/dV and dH/dT* are empty without ``jacobian`` (dH/dT* also without
    ``with_temperature``). ``th``, when given, is that tanh already computed.
    """
    temperature = np.asarray(temperature, np.float64)
    voltage = np.broadcast_to(np.asarray(voltage, np.float64), temperature.shape)
    local = np.ascontiguousarray(local, np.float64)
    if th is None:
        th = np.empty(temperature.shape)
        law_argument(temperature, voltage, local, curved, length, th)
        np.tanh(th, out=th)
    law = np.empty(temperature.shape)
    empty = np.empty((0, 0))
    by_voltage = np.empty(temperature.shape) if jacobian else empty
    by_temperature = np.empty(temperature.shape) if jacobian and with_temperature else empty
    coupled = voltage_by_temperature is not None
    by_play = (
        empty if voltage_by_temperature is None
        else np.broadcast_to(voltage_by_temperature, temperature.shape)
    )
    law_terms(temperature, voltage, th, local, curved, length, jacobian,
              jacobian and with_temperature, by_play, coupled, law, by_voltage, by_temperature,
              columns)
    return law, by_voltage, by_temperature, th
