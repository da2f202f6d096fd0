"""Inner loops of the feedforward modes: a pure-numpy path and a fused (numba) one.

The observer's PI loop runs ``iterations`` updates per set point, each a ``tanh`` and about
ten element-wise operations over the grid. In numpy every operation is one pass over the
grid and one call (about 1 us at 4096 actuators); the fused path compiles the arithmetic of
one update into a single loop (:func:`numba.njit`) and keeps ``np.tanh``, whose SIMD loop is
faster than the scalar ``tanh`` a compiled loop calls. Both paths do the same IEEE
operations in the same order (no fast-math), so they give the same numbers.

Which path runs (:func:`default_backend`): ``fused`` when numba is importable, else
``numpy``; the environment variable ``ES_DM_FEEDFORWARD_KERNELS=numpy`` forces numpy
(``fused`` demands numba and fails when it is missing). The fused loop is compiled once per
machine (cached beside the module, or in numba's user cache) when a feedforward that needs
it is built, not on the first set point.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Callable
from enum import StrEnum
from functools import cache
from typing import Final

import numpy as np

from es_physics.laws import LawsAtTemperature
from es_physics.params import FloatArray

#: Environment variable that chooses the kernels (values of :class:`Backend`, or ``auto``).
KERNELS_ENV: Final = "ES_DM_FEEDFORWARD_KERNELS"


class Backend(StrEnum):
    """Implementation of the feedforward's inner loops."""

    NUMPY = "numpy"
    FUSED = "fused"


class KernelBackendError(RuntimeError):
    """The requested kernels cannot be used (unknown name, or numba is missing)."""


@cache
def fused_available() -> bool:
    """Return whether numba is installed (the fused kernels need it).

    Looked up without importing it: numba's import takes most of a second, paid only by a
    feedforward whose mode has a fused kernel (:func:`prepare`).
    """
    return importlib.util.find_spec("numba") is not None


def default_backend() -> Backend:
    """Return the backend chosen by ``ES_DM_FEEDFORWARD_KERNELS`` (default ``auto``).

    Raises:
        KernelBackendError: the variable names no backend, or asks for ``fused`` without numba.

    """
    wanted = os.environ.get(KERNELS_ENV, "auto").strip().lower() or "auto"
    if wanted == "auto":
        return Backend.FUSED if fused_available() else Backend.NUMPY
    try:
        backend = Backend(wanted)
    except ValueError:
        choices = ", ".join(["auto", *(b.value for b in Backend)])
        raise KernelBackendError(f"{KERNELS_ENV}={wanted!r}: expected one of {choices}") from None
    if backend is Backend.FUSED and not fused_available():
        raise KernelBackendError(f"{KERNELS_ENV}=fused but numba cannot be imported")
    return backend


ObserverStep = Callable[
    [FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
     float, float, float],
    None,
]


@cache
def _fused_observer_step() -> ObserverStep:
    """Compile (or load from numba's cache) the fused observer update."""
    import numba

    @numba.njit(
        "void(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], "
        "float64[::1], float64[::1], float64, float64, float64)",
        cache=True,
        nogil=True,
        error_model="numpy",
    )
    def step(  # noqa: PLR0917 (numba calls are positional)
        u: FloatArray,
        integral: FloatArray,
        voltage: FloatArray,
        q: FloatArray,
        sqrt_n: FloatArray,
        sqrt_z_sat: FloatArray,
        target: FloatArray,
        v_limit: float,
        kp: float,
        ki: float,
    ) -> None:
        for i in range(u.size):
            t = u[i]
            gain = max((1.0 - t * t) * sqrt_n[i], 1e-6 * sqrt_n[i])
            error = (target[i] - sqrt_z_sat[i] * t) / gain
            held = min(max(integral[i] + ki * error, 0.0), v_limit)
            integral[i] = held
            v = held if kp == 0.0 else min(max(held + kp * error, 0.0), v_limit)
            voltage[i] = v
            u[i] = q[i] * v

    return step


def prepare(backend: Backend) -> None:
    """Compile the kernels of ``backend`` now (a no-op for numpy and after the first call)."""
    if backend is Backend.FUSED:
        _fused_observer_step()


def observer_iterations(
    integral: FloatArray,
    laws: LawsAtTemperature,
    target: FloatArray,
    *,
    v_limit: float,
    kp: float,
    ki: float,
    iterations: int,
    backend: Backend = Backend.NUMPY,
) -> tuple[FloatArray, FloatArray]:
    """Run the observer's PI loop towards ``target`` = sqrt(z) [sqrt(m)].

    Per update: t = tanh(q V), gain = max(sqrt_n (1 - t^2), 1e-6 sqrt_n),
    e = (target - sqrt_z_sat t) / gain, I = clip(I + ki e, 0, v_limit),
    V = I (kp = 0) or clip(I + kp e, 0, v_limit), with q, sqrt_n and sqrt_z_sat of ``laws``.

    Args:
        integral: integrator state [V], the grid's shape; not modified.
        laws: the model coefficients at the temperatures (same shape).
        target: sqrt of the set points [sqrt(m)], same shape.
        v_limit: largest voltage [V].
        kp: proportional gain (normalised by the local gain).
        ki: integral gain (normalised by the local gain).
        iterations: updates to run (>= 1).
        backend: which implementation runs (same numbers).

    Returns:
        (voltage, integral): new arrays [V]; with ``kp == 0`` they are the same array.

    """
    q, sqrt_n, sqrt_z_sat = laws.q, laws.sqrt_n, laws.sqrt_z_sat
    shape = integral.shape
    if backend is Backend.FUSED and integral.size:
        flat = [np.ascontiguousarray(a, np.float64).ravel()
                for a in (q, sqrt_n, sqrt_z_sat, target)]
        state = np.asarray(np.clip(integral, 0.0, v_limit), np.float64).ravel()
        # its own buffer even for kp = 0 (voltage == integral): a loop whose outputs may
        # overlap is not vectorised
        drive = np.empty_like(state)
        u = np.multiply(flat[0], state)
        step = _fused_observer_step()
        for _ in range(iterations):
            np.tanh(u, out=u)
            step(u, state, drive, flat[0], flat[1], flat[2], flat[3], v_limit, kp, ki)
        new_integral = state.reshape(shape)
        return (new_integral if kp == 0.0 else drive.reshape(shape)), new_integral
    zeros = np.zeros(shape)
    limit = np.full(shape, v_limit)
    floor = 1e-6 * sqrt_n
    new_integral = np.minimum(np.maximum(integral, zeros), limit)
    voltage = new_integral
    t = np.empty(shape)
    gain = np.empty(shape)
    error = np.empty(shape)
    for _ in range(iterations):
        np.multiply(q, voltage, out=t)
        np.tanh(t, out=t)
        # local gain of sqrt(z) over V: sqrt(M/L) sech^2(u)
        np.multiply(t, t, out=gain)
        np.subtract(1.0, gain, out=gain)
        gain *= sqrt_n
        np.maximum(gain, floor, out=gain)
        np.multiply(sqrt_z_sat, t, out=error)
        np.subtract(target, error, out=error)
        error /= gain
        new_integral += error if ki == 1.0 else ki * error
        np.maximum(new_integral, zeros, out=new_integral)  # anti-windup
        np.minimum(new_integral, limit, out=new_integral)
        if kp != 0.0:
            voltage = np.minimum(np.maximum(new_integral + kp * error, zeros), limit)
    return voltage, new_integral
