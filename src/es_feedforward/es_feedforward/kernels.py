"""Inner loops of the feedforward modes: a pure-numpy path and a fused (numba) one.

The observer's PI loop runs at most ``iterations`` updates per set point, each a ``tanh`` and
about ten element-wise operations over the grid; it stops before an update that would move
nothing by more than ``tolerance`` (from the last set point's command, a held set point
takes no update, a 10 Hz full-range sine at 2 kHz three). In numpy every operation is one
pass over the grid and one call (about 1 us at 4096 actuators); the fused path compiles the
arithmetic of one update into a single loop (:func:`numba.njit`), the set-up (sqrt of the
set points, clipped integrator) and the model error into one loop each, and keeps ``np.tanh``, whose
SIMD loop is faster than the scalar ``tanh`` a compiled loop calls. Both paths do the same
IEEE operations in the same order (no fast-math), so they give the same numbers. The tanh of
the final command is the model error's and, with kp = 0, the next set point's first update
(the integrator it starts from is that command): a caller that keeps it saves one of the
``updates + 1`` tanh passes exactly.

The hyperbolic inverse (the default mode) fuses the same way: one compiled pass checks the
ratios z / z_sat and takes their square roots, numpy's SIMD ``arctanh`` runs in place, one
compiled pass divides by q and limits (:func:`fused_hyperbolic_inverse`): three passes
instead of about ten numpy calls, reductions included. The first pass refuses any set point
the feedforward's cleaning would change (negative, not finite, above its ceiling) and the last
counts the clipped ones, so the feedforward's default path takes no other pass over the grid.
``linearized_dmax`` likewise: one compiled pass for the voltage, statuses and q V, numpy's
``tanh``, one compiled pass for the model error (:func:`fused_linearized`).

Which path runs (:func:`default_backend`): ``fused`` when numba is importable, else
``numpy``; the environment variable ``ES_DM_FEEDFORWARD_KERNELS=numpy`` forces numpy
(``fused`` demands numba and fails when it is missing). The fused loops are compiled once per
machine (cached beside the module, or in numba's user cache) and loaded when a feedforward
whose mode uses them is built (:func:`prepare`), not on the first set point.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from functools import cache, partial
from typing import Any, Final, NamedTuple

import numpy as np

from es_feedforward.feedforward_config import Mode
from es_physics.laws import (
    CODE_CLIPPED_HIGH,
    CODE_OK,
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


ObserverPrep = Callable[
    [FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, float],
    None,
]
ObserverFirstStep = Callable[
    [FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
     FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, float, float, float, float],
    int,
]
ObserverStep = Callable[
    [FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
     FloatArray, FloatArray, FloatArray, float, float, float, float],
    int,
]
ObserverFinish = Callable[[FloatArray, FloatArray, FloatArray, FloatArray], None]
HyperbolicRoot = Callable[[FloatArray, FloatArray, FloatArray, float, float], int]
HyperbolicScale = Callable[[FloatArray, FloatArray, StatusArray, float], int]
ReachLimit = Callable[[FloatArray, FloatArray, FloatArray, FloatArray, StatusArray, float], int]
LinearizedDrive = Callable[
    [FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
     StatusArray, FloatArray, float],
    int,
]
ForwardError = Callable[[FloatArray, FloatArray, FloatArray, FloatArray], None]


@dataclass(frozen=True)
class ObserverOutput:
    """What one set point's observer loop returns (arrays of the grid's shape).

    Attributes:
        voltage: the command [V]; the same array as ``integral`` when kp == 0.
        integral: the new integrator state [V].
        model_error: z_model(voltage) - z [m], with z = sqrt(max(z, 0))^2.
        tanh_of_voltage: tanh(q voltage): with kp == 0 the next set point's first update
            can start from it (``tanh_of_integral`` of :func:`observer_command`).
        updates: how many updates were applied (at most ``iterations``; fewer once the
            next would move nothing by more than the tolerance).

    """

    voltage: FloatArray
    integral: FloatArray
    model_error: FloatArray
    tanh_of_voltage: FloatArray
    updates: int


class _Compiler(NamedTuple):
    """numba, the array types of the kernels' signatures and the jit they compile with."""

    numba: Any
    vec: Any  # a writable 1-d float64 array
    ro: Any  # a read-only one: inputs may be frozen arrays (the node's last command is)
    jit: Callable[..., Any]


def _compiler() -> _Compiler:
    """Import numba (only the fused backend needs it) and return what the kernels use."""
    import numba

    return _Compiler(
        numba,
        numba.float64[::1],
        numba.types.Array(numba.float64, 1, "C", readonly=True),
        partial(numba.njit, cache=True, nogil=True, error_model="numpy"),
    )


@cache
def _fused_observer() -> tuple[ObserverPrep, ObserverFirstStep, ObserverStep, ObserverFinish]:
    """Compile (or load from numba's cache) the fused observer passes."""
    numba, vec, ro, jit = _compiler()
    f64 = numba.float64

    @numba.njit(inline="always", error_model="numpy")
    def update(  # noqa: PLR0917
        t: float,
        integral: float,
        voltage: float,
        target: float,
        coefficients: tuple[float, float, float],
        v_limit: float,
        kp: float,
        ki: float,
        tolerance: float,
    ) -> tuple[float, float, float, bool]:
        """One element's next integral, voltage and q voltage, and whether it moved."""
        q, sqrt_n, sqrt_z_sat = coefficients
        gain = max((1.0 - t * t) * sqrt_n, 1e-6 * sqrt_n)
        error = (target - sqrt_z_sat * t) / gain
        held = min(max(integral + ki * error, 0.0), v_limit)
        moved = abs(held - integral) > tolerance
        if kp == 0.0:
            return held, held, q * held, moved
        v = min(max(held + kp * error, 0.0), v_limit)
        return held, v, q * v, moved | (abs(v - voltage) > tolerance)

    @numba.njit(inline="always", error_model="numpy")
    def start(z: float, integral: float, v_limit: float) -> tuple[float, float]:
        """One element's sqrt(max(z, 0)) (a NaN stays NaN, as in np.clip) and clipped state."""
        if z < 0.0:  # noqa: PLR1730
            z = 0.0
        return np.sqrt(z), min(max(integral, 0.0), v_limit)

    @jit(numba.void(ro, ro, ro, vec, vec, vec, vec, f64))
    def prep(  # noqa: PLR0917 (numba calls are positional)
        z: FloatArray,
        integral: FloatArray,
        q: FloatArray,
        target: FloatArray,
        state: FloatArray,
        voltage: FloatArray,
        u: FloatArray,
        v_limit: float,
    ) -> None:
        for i in range(z.size):
            target[i], held = start(z[i], integral[i], v_limit)
            state[i] = held
            voltage[i] = held
            u[i] = q[i] * held

    # The steps count the elements that move by more than the tolerance instead of taking
    # the largest move: LLVM vectorises an integer sum but no float max without fast-math,
    # and a NaN move (a NaN set point) compares false, so it does not count. With kp == 0
    # the voltage is the integral: its buffers are neither read nor written.

    @jit(numba.int64(ro, ro, ro, vec, vec, vec, vec, vec, vec, ro, ro, ro, f64, f64, f64, f64))
    def first_step(  # noqa: PLR0917
        z: FloatArray,
        integral: FloatArray,
        t: FloatArray,
        target: FloatArray,
        state: FloatArray,
        voltage: FloatArray,
        next_integral: FloatArray,
        next_voltage: FloatArray,
        next_u: FloatArray,
        q: FloatArray,
        sqrt_n: FloatArray,
        sqrt_z_sat: FloatArray,
        v_limit: float,
        kp: float,
        ki: float,
        tolerance: float,
    ) -> int:
        """``prep`` and the first ``step`` in one pass, from the tanh the caller knows."""
        moved = 0
        for i in range(z.size):
            root, before = start(z[i], integral[i], v_limit)
            target[i] = root
            state[i] = before
            held, v, u, beyond = update(t[i], before, before, root,
                                        (q[i], sqrt_n[i], sqrt_z_sat[i]), v_limit, kp, ki,
                                        tolerance)  # fmt: skip
            next_integral[i] = held
            next_u[i] = u
            if kp != 0.0:
                voltage[i] = before
                next_voltage[i] = v
            moved += beyond
        return moved

    @jit(numba.int64(ro, ro, ro, vec, vec, vec, ro, ro, ro, ro, f64, f64, f64, f64))
    def step(  # noqa: PLR0917
        t: FloatArray,
        integral: FloatArray,
        voltage: FloatArray,
        next_integral: FloatArray,
        next_voltage: FloatArray,
        next_u: FloatArray,
        q: FloatArray,
        sqrt_n: FloatArray,
        sqrt_z_sat: FloatArray,
        target: FloatArray,
        v_limit: float,
        kp: float,
        ki: float,
        tolerance: float,
    ) -> int:
        moved = 0
        for i in range(t.size):
            before = integral[i]
            held, v, u, beyond = update(t[i], before, before if kp == 0.0 else voltage[i],
                                        target[i], (q[i], sqrt_n[i], sqrt_z_sat[i]), v_limit,
                                        kp, ki, tolerance)  # fmt: skip
            next_integral[i] = held
            next_u[i] = u
            if kp != 0.0:
                next_voltage[i] = v
            moved += beyond
        return moved

    @jit(numba.void(ro, ro, ro, vec))
    def finish(t: FloatArray, inv_zsat: FloatArray, target: FloatArray, error: FloatArray) -> None:
        for i in range(t.size):
            e = t[i] * t[i]
            error[i] = e / inv_zsat[i] - target[i] * target[i]

    return prep, first_step, step, finish


@cache
def _fused_reach_limit() -> ReachLimit:
    """Compile (or load from numba's cache) the fused reach status and voltage limit."""
    numba, vec, ro, jit = _compiler()
    high_code = np.int8(CODE_CLIPPED_HIGH)

    @jit(numba.int64(ro, ro, ro, vec, numba.int8[::1], numba.float64))
    def reach_limit(  # noqa: PLR0917 (numba calls are positional)
        z: FloatArray,
        below: FloatArray,
        beyond: FloatArray,
        voltage: FloatArray,
        status: StatusArray,
        v_limit: float,
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
            if not voltage[i] < v_limit:
                status[i] = high_code
                voltage[i] = v_limit
        return 0

    return reach_limit


@cache
def _fused_linearized() -> tuple[LinearizedDrive, ForwardError]:
    """Compile (or load from numba's cache) the passes around linearized_dmax's tanh."""
    numba, vec, ro, jit = _compiler()
    high_code = np.int8(CODE_CLIPPED_HIGH)

    # branch-free (selects and a counted reduction) so that LLVM vectorises it
    @jit(numba.int64(ro, ro, ro, ro, ro, ro, vec, numba.int8[::1], vec, numba.float64))
    def drive(  # noqa: PLR0917 (numba calls are positional)
        z: FloatArray,
        d_max: FloatArray,
        offset: FloatArray,
        q: FloatArray,
        below: FloatArray,
        beyond: FloatArray,
        voltage: FloatArray,
        status: StatusArray,
        u: FloatArray,
        v_limit: float,
    ) -> int:
        unclear = 0
        for i in range(z.size):
            zi = z[i]
            high = zi >= beyond[i]
            unclear += not (high or zi < below[i]) or not zi >= 0.0
            v = min(max(max(zi, 0.0) / d_max[i] + offset[i], 0.0), v_limit)
            over = not v < v_limit or high
            v = v_limit if over else v
            voltage[i] = v
            status[i] = high_code if over else np.int8(0)
            u[i] = q[i] * v
        return unclear

    @jit(numba.void(ro, ro, ro, vec))
    def forward_error(
        t: FloatArray, inv_zsat: FloatArray, z: FloatArray, error: FloatArray
    ) -> None:
        for i in range(t.size):
            e = t[i] * t[i]
            error[i] = e / inv_zsat[i] - z[i]

    return drive, forward_error


@cache
def _fused_hyperbolic() -> tuple[HyperbolicRoot, HyperbolicScale]:
    """Compile (or load from numba's cache) the passes around the hyperbolic inverse's arctanh."""
    numba, vec, ro, jit = _compiler()
    high_code = np.int8(CODE_CLIPPED_HIGH)

    # Both loops are branch-free (selects and a counted reduction) so that LLVM vectorises
    # them; an early exit or a conditional store would keep them scalar, 2-3x slower.
    @jit(numba.int64(ro, ro, vec, numba.float64, numba.float64))
    def root(
        z: FloatArray, inv_zsat: FloatArray, out: FloatArray, cap: float, ceiling: float
    ) -> int:
        bad = 0
        for i in range(z.size):
            zi = z[i]
            ratio = zi * inv_zsat[i]
            bad += not (ratio >= 0.0 and ratio < cap and zi <= ceiling)  # NaN fails too
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


def prepare(backend: Backend, mode: Mode) -> None:
    """Compile (or load) now the kernels ``mode`` uses.

    A no-op for numpy and for kernels already loaded. Loading from numba's cache took 0.6 s
    here for the default mode's (numba's import included) and 1.7 s more for the others: a
    feedforward pays it when it is built, not on its first set point.
    """
    if backend is Backend.FUSED:
        for load in _KERNELS_OF_MODE[mode]:
            load()


#: The compiled families each mode's command uses (the quadratic inverse uses none).
_KERNELS_OF_MODE: Final[dict[Mode, tuple[Callable[[], object], ...]]] = {
    Mode.INVERSE_HYPERBOLIC: (_fused_hyperbolic,),
    Mode.UNCOMPENSATED: (_fused_hyperbolic,),
    Mode.INVERSE_QUADRATIC: (),
    Mode.LINEARIZED_DMAX: (_fused_linearized,),
    Mode.OBSERVER: (_fused_observer, _fused_reach_limit),
}


def fused_hyperbolic_inverse(
    laws: LawsAtTemperature, z: FloatArray, v_limit: float, ceiling: float = np.inf
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
        ceiling: largest set point [m] taken here (a caller's own cleaning limit).

    Returns:
        Voltages and statuses (their largest code in ``worst``), or ``None`` when a set point
        is negative, not finite, above ``ceiling``, or at or beyond saturation (the numpy
        path's cleaning then applies).

    """
    root, scale = _fused_hyperbolic()
    voltage = np.empty(z.shape)
    flat = voltage.reshape(-1)
    z_flat = np.ascontiguousarray(z, np.float64).reshape(-1)
    inv_zsat = np.ascontiguousarray(laws.inv_zsat, np.float64).reshape(-1)
    if root(z_flat, inv_zsat, flat, RATIO_CAP, ceiling):
        return None
    np.arctanh(flat, out=flat)
    status = np.empty(z.shape, np.int8)
    q = np.ascontiguousarray(laws.q, np.float64).reshape(-1)
    clipped = scale(flat, q, status.reshape(-1), v_limit)
    return InverseResult(voltage, status, CODE_CLIPPED_HIGH if clipped else CODE_OK)


def fused_reach_status(
    z: FloatArray,
    voltage: FloatArray,
    below: FloatArray,
    beyond: FloatArray,
    v_limit: float,
) -> StatusArray | None:
    """Return the statuses of set points that are clearly in or beyond reach, and limit.

    One fused pass (numba) for laws that flag no actuator: status CLIPPED_HIGH where
    z >= ``beyond``, OK where z < ``below``; then, as :func:`es_physics.laws.limit_voltages`,
    voltages not below ``v_limit`` become ``v_limit`` (CLIPPED_HIGH). Needs the fused backend.

    Args:
        z: set points [m], the grid's shape.
        voltage: the command [V], same shape, C-contiguous; limited in place.
        below: set points [m] that ``v_limit`` surely reaches (same shape).
        beyond: set points [m] that ``v_limit`` surely does not reach (same shape).
        v_limit: largest voltage [V].

    Returns:
        The statuses, or ``None`` (``voltage`` untouched) when a set point is negative, not
        finite or between ``below`` and ``beyond``: the caller takes the model's inverse.

    """
    status = np.empty(z.shape, np.int8)
    z_flat, below_flat, beyond_flat = (
        np.ascontiguousarray(a, np.float64).ravel() for a in (z, below, beyond)
    )
    unclear = _fused_reach_limit()(
        z_flat, below_flat, beyond_flat, voltage.reshape(-1), status.reshape(-1), v_limit
    )
    return None if unclear else status


def fused_linearized(
    laws: LawsAtTemperature, z: FloatArray, below: FloatArray, beyond: FloatArray,
    v_limit: float,
) -> tuple[InverseResult, FloatArray] | None:
    """Return the ``linearized_dmax`` command and its model error in three passes.

    V = clip(max(z, 0) / d_max + linear_offset, 0, v_limit), driven at ``v_limit`` where z is
    beyond reach (status CLIPPED_HIGH, as where V reaches the limit), and z_model(V) - z: one
    compiled pass for the voltage, statuses and q V, numpy's SIMD ``tanh`` in place, one
    compiled pass for the error. The numpy path's IEEE operations in the same order, so the
    same numbers. For laws that flag no actuator.

    Args:
        laws: the model at the temperatures, no actuator flagged.
        z: free-displacement set points [m], the laws' shape.
        below: set points [m] that ``v_limit`` surely reaches (same shape).
        beyond: set points [m] that ``v_limit`` surely does not reach (same shape).
        v_limit: largest voltage [V].

    Returns:
        (voltages and statuses, model error [m]), or ``None`` when a set point is negative,
        not finite or between ``below`` and ``beyond`` (the caller takes the numpy path).

    """
    z_flat, d_max, offset, q, inv_zsat, below_flat, beyond_flat = (
        np.ascontiguousarray(a, np.float64).ravel()
        for a in (z, laws.d_max, laws.linear_offset, laws.q, laws.inv_zsat, below, beyond)
    )
    drive, forward_error = _fused_linearized()
    voltage, u = np.empty(z_flat.size), np.empty(z_flat.size)
    status = np.empty(z_flat.size, np.int8)
    if drive(z_flat, d_max, offset, q, below_flat, beyond_flat, voltage, status, u, v_limit):
        return None
    np.tanh(u, out=u)
    error = np.empty(z_flat.size)  # not u: a loop whose output may overlap is not vectorised
    forward_error(u, inv_zsat, z_flat, error)
    shape = z.shape
    return InverseResult(voltage.reshape(shape), status.reshape(shape)), error.reshape(shape)


def observer_command(
    integral: FloatArray,
    laws: LawsAtTemperature,
    z: FloatArray,
    *,
    v_limit: float,
    kp: float,
    ki: float,
    iterations: int,
    tolerance: float = 0.0,
    backend: Backend = Backend.NUMPY,
    tanh_of_integral: FloatArray | None = None,
) -> ObserverOutput:
    """Run the observer's PI loop towards sqrt(z) and the forward model at its result.

    With target = sqrt(max(z, 0)), per update: t = tanh(q V), gain = max(sqrt_n (1 - t^2),
    1e-6 sqrt_n), e = (target - sqrt_z_sat t) / gain, I = clip(I + ki e, 0, v_limit),
    V = I (kp = 0) or clip(I + kp e, 0, v_limit), with q, sqrt_n and sqrt_z_sat of ``laws``;
    V starts at clip(I, 0, v_limit). The loop stops after ``iterations`` updates, or earlier
    when the next update would move no element's I or V by more than ``tolerance`` (that
    update is not applied; elements whose move is NaN do not count). The model error takes
    t = tanh(q V) of the final V, which the next call's first update reuses when kp == 0
    (exactly the same number, one tanh pass less per set point).

    Args:
        integral: integrator state [V], the grid's shape; not modified.
        laws: the model coefficients at the temperatures (same shape).
        z: free-displacement set points [m], same shape (negative ones count as 0).
        v_limit: largest voltage [V].
        kp: proportional gain (normalised by the local gain).
        ki: integral gain (normalised by the local gain).
        iterations: most updates to run (>= 1).
        tolerance: largest move [V] of an update that is not worth applying (>= 0; 0 stops
            only at a fixed point, where every further update would repeat it exactly).
        backend: which implementation runs (same numbers).
        tanh_of_integral: tanh(q clip(integral, 0, v_limit)) when the caller knows it (the
            ``tanh_of_voltage`` of the call that returned ``integral`` with kp == 0).

    Returns:
        The new arrays (:class:`ObserverOutput`).

    """
    shape = integral.shape
    if backend is Backend.FUSED and integral.size:
        return _fused_command(
            integral, laws, z, v_limit, kp, ki, iterations, tolerance, tanh_of_integral
        )
    q, sqrt_n, sqrt_z_sat = laws.q, laws.sqrt_n, laws.sqrt_z_sat
    target = np.sqrt(np.clip(z, 0.0, None))
    zeros = np.zeros(shape)
    limit = np.full(shape, v_limit)
    floor = 1e-6 * sqrt_n
    new_integral = np.minimum(np.maximum(integral, zeros), limit)
    voltage = new_integral
    if tanh_of_integral is not None:
        t = np.array(tanh_of_integral, np.float64)
    else:
        t = np.tanh(q * voltage)
    gain = np.empty(shape)
    error = np.empty(shape)
    updates = 0
    while True:
        # local gain of sqrt(z) over V: sqrt(M/L) sech^2(u)
        np.multiply(t, t, out=gain)
        np.subtract(1.0, gain, out=gain)
        gain *= sqrt_n
        np.maximum(gain, floor, out=gain)
        np.multiply(sqrt_z_sat, t, out=error)
        np.subtract(target, error, out=error)
        error /= gain
        next_integral = new_integral + (error if ki == 1.0 else ki * error)
        np.maximum(next_integral, zeros, out=next_integral)  # anti-windup
        np.minimum(next_integral, limit, out=next_integral)
        next_voltage = next_integral
        if kp != 0.0:
            next_voltage = np.minimum(np.maximum(next_integral + kp * error, zeros), limit)
        if not _moved(new_integral, next_integral, voltage, next_voltage, tolerance):
            break  # converged: the update is not applied, t is still tanh(q voltage)
        new_integral, voltage = next_integral, next_voltage
        updates += 1
        np.multiply(q, voltage, out=t)
        np.tanh(t, out=t)
        if updates == iterations:
            break
    model_error = t * t
    model_error /= laws.inv_zsat
    target *= target
    model_error -= target
    return ObserverOutput(voltage, new_integral, model_error, t, updates)


def _moved(
    integral_before: FloatArray, integral: FloatArray, voltage_before: FloatArray,
    voltage: FloatArray, tolerance: float,
) -> int:
    """Count the elements whose integrator or voltage moved by more than ``tolerance``.

    The fused steps' rule: a NaN move compares false, so it does not count.
    """
    beyond = np.abs(integral - integral_before) > tolerance
    beyond |= np.abs(voltage - voltage_before) > tolerance
    return int(np.count_nonzero(beyond))


def _fused_command(  # noqa: PLR0917 (the arguments of observer_command)
    integral: FloatArray,
    laws: LawsAtTemperature,
    z: FloatArray,
    v_limit: float,
    kp: float,
    ki: float,
    iterations: int,
    tolerance: float,
    tanh_of_integral: FloatArray | None,
) -> ObserverOutput:
    """:func:`observer_command` in numba passes around numpy's SIMD ``tanh``."""
    shape = integral.shape
    q, sqrt_n, sqrt_z_sat, inv_zsat, z_flat, state = (
        np.ascontiguousarray(a, np.float64).ravel()
        for a in (laws.q, laws.sqrt_n, laws.sqrt_z_sat, laws.inv_zsat, z, integral)
    )
    prep, first_step, step, finish = _fused_observer()
    size = q.size
    target = np.empty(size)
    # the state and its next values: a step writes the next ones, and they become the state
    # only if the step moved something by more than the tolerance
    held, drive = np.empty(size), np.empty(size)
    next_held, next_drive, next_u = np.empty(size), np.empty(size), np.empty(size)
    known = None
    if tanh_of_integral is None:
        u = np.empty(size)
        prep(z_flat, state, q, target, held, drive, u, v_limit)
        np.tanh(u, out=u)
    else:  # the first update needs no tanh: one pass sets up and takes it
        u = known = np.ascontiguousarray(tanh_of_integral, np.float64).ravel()
        moved = first_step(z_flat, state, u, target, held, drive, next_held, next_drive, next_u,
                           q, sqrt_n, sqrt_z_sat, v_limit, kp, ki, tolerance)  # fmt: skip
    updates = 0
    while True:
        if updates or known is None:
            moved = step(u, held, drive, next_held, next_drive, next_u, q, sqrt_n, sqrt_z_sat,
                         target, v_limit, kp, ki, tolerance)  # fmt: skip
        if not moved:
            break  # converged: the update is not applied, u is still tanh(q voltage)
        held, next_held = next_held, held
        drive, next_drive = next_drive, drive
        u, next_u = next_u, (np.empty(size) if u is known else u)  # never write the caller's
        updates += 1
        np.tanh(u, out=u)
        if updates == iterations:
            break
    error = next_u  # spent, and never the caller's
    finish(u, inv_zsat, target, error)
    new_integral = held.reshape(shape)
    voltage = new_integral if kp == 0.0 else drive.reshape(shape)
    return ObserverOutput(voltage, new_integral, error.reshape(shape), u.reshape(shape), updates)
