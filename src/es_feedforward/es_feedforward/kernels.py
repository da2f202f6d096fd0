"""Inner loops of the feedforward modes: a pure-numpy path and a fused (numba) one.

The observer's PI loop runs ``iterations`` updates per set point, each a ``tanh`` and about
ten element-wise operations over the grid. In numpy every operation is one pass over the
grid and one call (about 1 us at 4096 actuators); the fused path compiles the arithmetic of
one update into a single loop (:func:`numba.njit`), the set-up (sqrt of the set points,
clipped integrator) and the model error into one loop each, and keeps ``np.tanh``, whose
SIMD loop is faster than the scalar ``tanh`` a compiled loop calls. Both paths do the same
IEEE operations in the same order (no fast-math), so they give the same numbers. The tanh of
the final command is the model error's and, with kp = 0, the next set point's first update
(the integrator it starts from is that command): a caller that keeps it saves one of the
``iterations + 1`` tanh passes exactly.

The hyperbolic inverse (the default mode) fuses the same way: one compiled pass checks the
ratios z / z_sat and takes their square roots, numpy's SIMD ``arctanh`` runs in place, one
compiled pass divides by q and limits (:func:`fused_hyperbolic_inverse`): three passes
instead of about ten numpy calls, reductions included.

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
from dataclasses import dataclass
from enum import StrEnum
from functools import cache, partial
from typing import Final

import numpy as np

from es_physics.laws import (
    CODE_CLIPPED_HIGH,
    RATIO_CAP,
    InverseResult,
    LawsAtTemperature,
    StatusArray,
)
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
ObserverPrep = Callable[
    [FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
     float, bool],
    None,
]
ObserverFinish = Callable[[FloatArray, FloatArray, FloatArray, FloatArray], None]
HyperbolicRoot = Callable[[FloatArray, FloatArray, FloatArray, float], int]
HyperbolicScale = Callable[[FloatArray, FloatArray, StatusArray, float], int]
ReachLimit = Callable[
    [FloatArray, FloatArray, FloatArray, FloatArray, StatusArray, float, bool], int
]


@dataclass(frozen=True)
class ObserverOutput:
    """What one set point's observer loop returns (arrays of the grid's shape).

    Attributes:
        voltage: the command [V]; the same array as ``integral`` when kp == 0.
        integral: the new integrator state [V].
        model_error: z_model(voltage) - z [m], with z = sqrt(max(z, 0))^2.
        tanh_of_voltage: tanh(q voltage): with kp == 0 the next set point's first update
            can start from it (``tanh_of_integral`` of :func:`observer_command`).

    """

    voltage: FloatArray
    integral: FloatArray
    model_error: FloatArray
    tanh_of_voltage: FloatArray


@cache
def _fused_observer() -> tuple[ObserverPrep, ObserverStep, ObserverFinish]:
    """Compile (or load from numba's cache) the fused observer passes."""
    import numba

    vec = numba.float64[::1]
    # inputs may be frozen arrays (the node's last command is read-only)
    ro = numba.types.Array(numba.float64, 1, "C", readonly=True)
    f64 = numba.float64
    jit = partial(numba.njit, cache=True, nogil=True, error_model="numpy")

    @jit(numba.void(ro, ro, ro, ro, vec, vec, vec, f64, numba.boolean))
    def prep(  # noqa: PLR0917 (numba calls are positional)
        z: FloatArray,
        integral: FloatArray,
        q: FloatArray,
        known_tanh: FloatArray,
        target: FloatArray,
        state: FloatArray,
        u: FloatArray,
        v_limit: float,
        have_tanh: bool,
    ) -> None:
        for i in range(z.size):
            zi = z[i]
            if zi < 0.0:  # noqa: PLR1730 (a NaN stays NaN, as in np.clip)
                zi = 0.0
            target[i] = np.sqrt(zi)
            held = min(max(integral[i], 0.0), v_limit)
            state[i] = held
            u[i] = known_tanh[i] if have_tanh else q[i] * held

    @jit(numba.void(vec, vec, vec, ro, ro, ro, vec, f64, f64, f64))
    def step(  # noqa: PLR0917
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

    @jit(numba.void(vec, ro, vec, vec))
    def finish(t: FloatArray, inv_zsat: FloatArray, target: FloatArray, error: FloatArray) -> None:
        for i in range(t.size):
            e = t[i] * t[i]
            error[i] = e / inv_zsat[i] - target[i] * target[i]

    return prep, step, finish


@cache
def _fused_reach_limit() -> ReachLimit:
    """Compile (or load from numba's cache) the fused reach status and voltage limit."""
    import numba

    vec = numba.float64[::1]
    ro = numba.types.Array(numba.float64, 1, "C", readonly=True)
    high_code = np.int8(CODE_CLIPPED_HIGH)

    @numba.njit(numba.int64(ro, ro, ro, vec, numba.int8[::1], numba.float64, numba.boolean),
                cache=True, nogil=True, error_model="numpy")
    def reach_limit(  # noqa: PLR0917 (numba calls are positional)
        z: FloatArray,
        below: FloatArray,
        beyond: FloatArray,
        voltage: FloatArray,
        status: StatusArray,
        v_limit: float,
        saturate_high: bool,
    ) -> int:
        unclear = 0
        for i in range(z.size):
            zi = z[i]
            high = zi >= beyond[i]
            status[i] = high_code if high else np.int8(0)
            unclear += not (high or zi < below[i]) or not zi >= 0.0
        if unclear:
            return unclear
        for i in range(z.size):
            if not voltage[i] < v_limit or (saturate_high and status[i] == high_code):
                status[i] = high_code
                voltage[i] = v_limit
        return 0

    return reach_limit


@cache
def _fused_hyperbolic() -> tuple[HyperbolicRoot, HyperbolicScale]:
    """Compile (or load from numba's cache) the passes around the hyperbolic inverse's arctanh."""
    import numba

    vec = numba.float64[::1]
    ro = numba.types.Array(numba.float64, 1, "C", readonly=True)
    high_code = np.int8(CODE_CLIPPED_HIGH)
    jit = partial(numba.njit, cache=True, nogil=True, error_model="numpy")

    # Both loops are branch-free (selects and a counted reduction) so that LLVM vectorises
    # them; an early exit or a conditional store would keep them scalar, 2-3x slower.
    @jit(numba.int64(ro, ro, vec, numba.float64))
    def root(z: FloatArray, inv_zsat: FloatArray, out: FloatArray, cap: float) -> int:
        bad = 0
        for i in range(z.size):
            ratio = z[i] * inv_zsat[i]
            bad += not (ratio >= 0.0 and ratio < cap)  # NaN fails too
            out[i] = np.sqrt(ratio)
        return bad

    @jit(numba.int64(vec, ro, numba.int8[::1], numba.float64))
    def scale(voltage: FloatArray, q: FloatArray, status: StatusArray, v_limit: float) -> int:
        clipped = 0
        for i in range(voltage.size):
            v = voltage[i] / q[i]
            over = not v < v_limit  # a NaN is clipped too, as in limit_voltages
            voltage[i] = v_limit if over else v
            status[i] = high_code if over else np.int8(0)
            clipped += over
        return clipped

    return root, scale


def prepare(backend: Backend) -> None:
    """Compile the kernels of ``backend`` now (a no-op for numpy and after the first call)."""
    if backend is Backend.FUSED:
        _fused_observer()
        _fused_reach_limit()
        _fused_hyperbolic()


def fused_hyperbolic_inverse(
    laws: LawsAtTemperature, z: FloatArray, v_limit: float
) -> InverseResult | None:
    """Return ``laws.hyperbolic_inverse(z, v_limit)`` in three passes instead of about ten.

    A compiled pass checks every ratio z / z_sat and takes its square root, numpy's SIMD
    ``arctanh`` runs in place (faster than the scalar one a compiled loop would call), and a
    compiled pass divides by q and limits at ``v_limit``. The same IEEE operations in the same
    order as the numpy path, so the same numbers. For laws that flag no actuator.

    Args:
        laws: the model at the temperatures, no actuator flagged.
        z: free-displacement set points [m], the laws' shape.
        v_limit: largest voltage [V].

    Returns:
        Voltages and statuses, or ``None`` when a set point is negative, not finite or at or
        beyond saturation (the numpy path's cleaning then applies).

    """
    z_flat, inv_zsat, q = (
        np.ascontiguousarray(a, np.float64).ravel() for a in (z, laws.inv_zsat, laws.q)
    )
    root, scale = _fused_hyperbolic()
    voltage = np.empty(z_flat.size)
    if root(z_flat, inv_zsat, voltage, RATIO_CAP):
        return None
    np.arctanh(voltage, out=voltage)
    status = np.empty(z_flat.size, np.int8)
    scale(voltage, q, status, v_limit)
    return InverseResult(voltage.reshape(z.shape), status.reshape(z.shape))


def fused_reach_status(
    z: FloatArray,
    voltage: FloatArray,
    below: FloatArray,
    beyond: FloatArray,
    v_limit: float,
    *,
    saturate_high: bool = False,
) -> StatusArray | None:
    """Return the statuses of set points that are clearly in or beyond reach, and limit.

    One fused pass (numba) for laws that flag no actuator: status CLIPPED_HIGH where
    z >= ``beyond``, OK where z < ``below``; then, as :func:`es_physics.laws.limit_voltages`,
    voltages not below ``v_limit`` become ``v_limit`` (CLIPPED_HIGH), and so do the
    CLIPPED_HIGH set points' voltages with ``saturate_high``. Needs the fused backend.

    Args:
        z: set points [m], the grid's shape.
        voltage: the command [V], same shape, C-contiguous; limited in place.
        below: set points [m] that ``v_limit`` surely reaches (same shape).
        beyond: set points [m] that ``v_limit`` surely does not reach (same shape).
        v_limit: largest voltage [V].
        saturate_high: drive the set points beyond reach at ``v_limit``.

    Returns:
        The statuses, or ``None`` (``voltage`` untouched) when a set point is negative, not
        finite or between ``below`` and ``beyond``: the caller takes the model's inverse.

    """
    status = np.empty(z.shape, np.int8)
    z_flat, below_flat, beyond_flat = (
        np.ascontiguousarray(a, np.float64).ravel() for a in (z, below, beyond)
    )
    unclear = _fused_reach_limit()(
        z_flat, below_flat, beyond_flat, voltage.reshape(-1), status.reshape(-1), v_limit,
        saturate_high,
    )
    return None if unclear else status


def observer_command(
    integral: FloatArray,
    laws: LawsAtTemperature,
    z: FloatArray,
    *,
    v_limit: float,
    kp: float,
    ki: float,
    iterations: int,
    backend: Backend = Backend.NUMPY,
    tanh_of_integral: FloatArray | None = None,
) -> ObserverOutput:
    """Run the observer's PI loop towards sqrt(z) and the forward model at its result.

    With target = sqrt(max(z, 0)), per update: t = tanh(q V), gain = max(sqrt_n (1 - t^2),
    1e-6 sqrt_n), e = (target - sqrt_z_sat t) / gain, I = clip(I + ki e, 0, v_limit),
    V = I (kp = 0) or clip(I + kp e, 0, v_limit), with q, sqrt_n and sqrt_z_sat of ``laws``;
    V starts at clip(I, 0, v_limit). The model error takes t = tanh(q V) of the final V,
    which the next call's first update reuses when kp == 0 (exactly the same number, one
    tanh pass less per set point).

    Args:
        integral: integrator state [V], the grid's shape; not modified.
        laws: the model coefficients at the temperatures (same shape).
        z: free-displacement set points [m], same shape (negative ones count as 0).
        v_limit: largest voltage [V].
        kp: proportional gain (normalised by the local gain).
        ki: integral gain (normalised by the local gain).
        iterations: updates to run (>= 1).
        backend: which implementation runs (same numbers).
        tanh_of_integral: tanh(q clip(integral, 0, v_limit)) when the caller knows it (the
            ``tanh_of_voltage`` of the call that returned ``integral`` with kp == 0).

    Returns:
        The new arrays (:class:`ObserverOutput`).

    """
    shape = integral.shape
    if backend is Backend.FUSED and integral.size:
        return _fused_command(integral, laws, z, v_limit, kp, ki, iterations, tanh_of_integral)
    q, sqrt_n, sqrt_z_sat = laws.q, laws.sqrt_n, laws.sqrt_z_sat
    target = np.sqrt(np.clip(z, 0.0, None))
    zeros = np.zeros(shape)
    limit = np.full(shape, v_limit)
    floor = 1e-6 * sqrt_n
    new_integral = np.minimum(np.maximum(integral, zeros), limit)
    voltage = new_integral
    t = np.empty(shape)
    gain = np.empty(shape)
    error = np.empty(shape)
    for k in range(iterations):
        if k == 0 and tanh_of_integral is not None:
            t[...] = tanh_of_integral
        else:
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
    np.multiply(q, voltage, out=t)
    np.tanh(t, out=t)
    model_error = t * t
    model_error /= laws.inv_zsat
    target *= target
    model_error -= target
    return ObserverOutput(voltage, new_integral, model_error, t)


def _fused_command(  # noqa: PLR0917 (the arguments of observer_command)
    integral: FloatArray,
    laws: LawsAtTemperature,
    z: FloatArray,
    v_limit: float,
    kp: float,
    ki: float,
    iterations: int,
    tanh_of_integral: FloatArray | None,
) -> ObserverOutput:
    """:func:`observer_command` in numba passes around numpy's SIMD ``tanh``."""
    shape = integral.shape
    q, sqrt_n, sqrt_z_sat, inv_zsat, z_flat, state = (
        np.ascontiguousarray(a, np.float64).ravel()
        for a in (laws.q, laws.sqrt_n, laws.sqrt_z_sat, laws.inv_zsat, z, integral)
    )
    have_tanh = tanh_of_integral is not None
    known = np.ascontiguousarray(tanh_of_integral, np.float64).ravel() if have_tanh else q
    prep, step, finish = _fused_observer()
    target, held, u = np.empty(q.size), np.empty(q.size), np.empty(q.size)
    prep(z_flat, state, q, known, target, held, u, v_limit, have_tanh)
    # its own buffer even for kp = 0 (voltage == integral): a loop whose outputs may
    # overlap is not vectorised
    drive = np.empty_like(held)
    for k in range(iterations):
        if k or not have_tanh:
            np.tanh(u, out=u)
        step(u, held, drive, q, sqrt_n, sqrt_z_sat, target, v_limit, kp, ki)
    np.tanh(u, out=u)
    error = np.empty_like(u)
    finish(u, inv_zsat, target, error)
    new_integral = held.reshape(shape)
    voltage = new_integral if kp == 0.0 else drive.reshape(shape)
    return ObserverOutput(voltage, new_integral, error.reshape(shape), u.reshape(shape))
