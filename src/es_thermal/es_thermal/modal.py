"""Discretisation and steady-state Kalman filter of a network that falls apart into groups.

In modal coordinates (:func:`es_thermal.network.modal_model`) the thermal network is block
diagonal: the states and measurements form many small independent groups (connected
components of the coupling graph). Each group is discretised (zero-order hold) and its filter
Riccati equation solved on its own; groups of the same size are stacked and solved in one
batched call, so a 64 x 64 grid (thousands of groups) costs a few batched small-matrix
operations, not thousands of Python-level solves or one dense 8193 x 8193 equation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, sparse
from scipy.sparse import csgraph

from es_common.arrays import FloatArray, IndexArray
from es_thermal.errors import ConvergenceError


def discretise(A: FloatArray, B: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    """Return the zero-order-hold discretisation (A_d, B_d) of dx/dt = A x + B u over ``dt``.

    ``A`` (..., n, n) and ``B`` (..., n, m) may carry leading batch dimensions.
    """
    n, m = B.shape[-2:]
    augmented = np.zeros((*A.shape[:-2], n + m, n + m))
    augmented[..., :n, :n] = A * dt
    augmented[..., :n, n:] = B * dt
    phi = linalg.expm(augmented)
    return phi[..., :n, :n], phi[..., :n, n:]


def steady_state_covariance(
    A: FloatArray,
    H: FloatArray,
    Q: FloatArray,
    R: FloatArray,
    *,
    tol: float = 1e-12,
    max_iter: int = 80,
) -> FloatArray:
    """Return the steady-state prior covariance P of the Kalman filter for (A, H, Q, R).

    P solves the filter DARE ``P = A P A' - A P H' (H P H' + R)^-1 H P A' + Q``; the
    structure-preserving doubling algorithm gets there in a few dozen iterations
    (quadratic convergence) even when the slowest mode barely decays per sample. Every
    argument may carry the same leading batch dimensions (independent problems).

    Raises:
        ConvergenceError: no convergence (the pair (A, H) is not detectable).

    """
    n = A.shape[-1]

    def t(x: FloatArray) -> FloatArray:
        return np.swapaxes(x, -1, -2)

    Ak = t(A).copy()
    Gk = t(H) @ np.linalg.solve(R, H)
    Hk = Q.copy()
    eye = np.eye(n)
    for _ in range(max_iter):
        W = eye + Gk @ Hk
        Y = np.linalg.solve(W, np.concatenate([Ak, Gk], axis=-1))
        Y_a, Y_g = Y[..., :n], Y[..., n:]
        H_next = Hk + t(Ak) @ Hk @ Y_a
        Gk = Gk + Ak @ Y_g @ t(Ak)
        Ak = Ak @ Y_a
        change = np.max(np.abs(H_next - Hk), axis=(-2, -1))
        Hk = 0.5 * (H_next + t(H_next))
        if np.all(change <= tol * np.maximum(1.0, np.max(np.abs(Hk), axis=(-2, -1)))):
            return np.asarray(Hk, float)
    raise ConvergenceError("Kalman gain: the Riccati iteration did not converge")


@dataclass(frozen=True)
class ModalSolution:
    """Discretised network and steady-state filter, in the coordinates they were given in.

    Attributes:
        A_d: state transition over one sample (n x n, sparse).
        B_d: input matrix over one sample, input held (n x m, sparse).
        gain: steady-state Kalman gain (n x s, sparse).
        innovation_cov: steady-state innovation covariance H P H' + R (s x s, sparse).

    """

    A_d: sparse.csr_matrix
    B_d: sparse.csr_matrix
    gain: sparse.csr_matrix
    innovation_cov: sparse.csr_matrix


@dataclass(frozen=True)
class _Groups:
    """Groups of one size: global indices (g, size) of their states, measurements, inputs."""

    states: IndexArray
    measurements: IndexArray
    inputs: IndexArray


def modal_solution(
    A: sparse.spmatrix,
    B: sparse.spmatrix,
    H: sparse.spmatrix,
    *,
    q: FloatArray,
    r: float,
    dt: float,
) -> ModalSolution:
    """Discretise (A, B) over ``dt`` and solve the filter DARE group by group.

    Args:
        A: continuous state matrix (n x n) [1/s].
        B: continuous input matrix (n x m).
        H: measurement matrix (s x n).
        q: process noise variance per state over one sample (n,) (diagonal Q).
        r: measurement noise variance (R = r I).
        dt: sample period [s].

    An irregular sensor layout couples everything into one group, and this becomes the
    dense solution.

    Raises:
        ConvergenceError: the Riccati iteration did not converge.

    """
    A, B, H = sparse.csr_matrix(A), sparse.csr_matrix(B), sparse.csr_matrix(H)
    n, m, s = A.shape[0], B.shape[1], H.shape[0]
    labels = _component_labels(A, B, H)
    classes = _group(labels, (n, s, m))
    a_parts, b_parts, k_parts, c_parts = [], [], [], []
    for groups in classes:
        st, ms, ins = groups.states, groups.measurements, groups.inputs
        if st.shape[1] == 0:
            continue
        Ad, Bd = discretise(_blocks(A, st, st), _blocks(B, st, ins), dt)
        a_parts.append((st, st, Ad))
        b_parts.append((st, ins, Bd))
        if ms.shape[1] == 0:
            continue  # unobserved and stable (the Laplacian's higher modes decay to the base)
        Hc = _blocks(H, ms, st)
        R = r * np.eye(ms.shape[1])
        Q = q[st][:, :, None] * np.eye(st.shape[1])
        P = steady_state_covariance(Ad, Hc, Q, np.broadcast_to(R, (len(st), *R.shape)))
        HP = Hc @ P
        cov = HP @ np.swapaxes(Hc, -1, -2) + R
        k_parts.append((st, ms, np.swapaxes(np.linalg.solve(cov, HP), -1, -2)))
        c_parts.append((ms, ms, cov))
    return ModalSolution(
        _scatter(a_parts, (n, n)),
        _scatter(b_parts, (n, m)),
        _scatter(k_parts, (n, s)),
        _scatter(c_parts, (s, s)),
    )


def jump_gains(
    A_d: sparse.spmatrix,
    H: sparse.spmatrix,
    *,
    q: FloatArray,
    r: float,
    state: int,
    variance: float,
    tol: float = 1e-3,
    max_samples: int = 100_000,
) -> tuple[sparse.csr_matrix, ...]:
    """Return the gains that follow a jump of ``state`` by a random amount of ``variance``.

    After the jump the gain is time-varying (the Riccati recursion from the steady-state
    covariance raised by the jump's variance) until it is the steady-state gain again. Only
    the jumping state's group of coupled states and measurements differs from the steady
    state, so each sample's gain is returned as its difference from the steady-state gain
    (n x s, sparse, nonzero on that group only), one per sample after the jump.

    The jump happened during the sample before the first gain's: the prior covariance is
    the steady state's plus ``variance`` along the jumping state's column of ``A_d``. The
    gains run until they are within ``tol`` (relative to the largest entry) of the steady
    state's, at most ``max_samples``.

    Args:
        A_d: discretised state transition (n x n), block diagonal by group.
        H: measurement matrix (s x n).
        q: process noise variance per state over one sample (n,).
        r: measurement noise variance (R = r I).
        state: index of the jumping state.
        variance: the jump's variance.
        tol: relative tolerance of the return to the steady-state gain.
        max_samples: cap on the number of gains.

    Raises:
        ConvergenceError: the steady-state Riccati iteration did not converge.

    """
    A_d, H = sparse.csr_matrix(A_d), sparse.csr_matrix(H)
    n, s = A_d.shape[0], H.shape[0]
    labels = _component_labels(A_d, sparse.csr_matrix((n, 1)), H)  # one idle input
    states = np.flatnonzero(labels[:n] == labels[state])
    measurements = np.flatnonzero(labels[n:n + s] == labels[state])
    A = A_d[states][:, states].toarray()
    Hg = H[measurements][:, states].toarray()
    Q = np.diag(q[states])
    R = r * np.eye(measurements.size)
    P = steady_state_covariance(A, Hg, Q, R)
    steady_cov = Hg @ P @ Hg.T + R
    steady_gain = np.linalg.solve(steady_cov, Hg @ P).T
    column = A[:, int(np.searchsorted(states, state))]
    P = P + variance * np.outer(column, column)
    scale = tol * max(float(np.max(np.abs(steady_gain))), float(np.finfo(float).tiny))

    corrections: list[sparse.csr_matrix] = []
    for _ in range(max_samples):
        cov = Hg @ P @ Hg.T + R
        gain = np.linalg.solve(cov, Hg @ P).T
        if corrections and np.max(np.abs(gain - steady_gain)) <= scale:
            break
        corrections.append(_scatter([(states[None, :], measurements[None, :],
                                      (gain - steady_gain)[None])], (n, s)))
        P = A @ (P - gain @ Hg @ P) @ A.T + Q
        P = 0.5 * (P + P.T)
    return tuple(corrections)


def _component_labels(
    A: sparse.csr_matrix, B: sparse.csr_matrix, H: sparse.csr_matrix
) -> IndexArray:
    """Label states, measurements and inputs (in that order) by coupled group."""
    m, s = B.shape[1], H.shape[0]
    graph = sparse.bmat(
        [
            [A != 0.0, (H != 0.0).T, B != 0.0],
            [H != 0.0, sparse.csr_matrix((s, s)), None],
            [(B != 0.0).T, None, sparse.csr_matrix((m, m))],
        ],
        format="csr",
    )
    _, labels = csgraph.connected_components(graph, directed=False)
    return np.asarray(labels, np.intp)


def _group(labels: IndexArray, sizes: tuple[int, int, int]) -> list[_Groups]:
    """Return the groups by size class.

    Within a group, states, measurements and inputs keep their ascending global order.
    """
    kinds = np.repeat(np.arange(3), sizes)
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    count = int(labels.max()) + 1 if labels.size else 0
    per_kind = np.zeros((count, 3), np.intp)
    np.add.at(per_kind, (labels, kinds), 1)
    order = np.lexsort((np.arange(labels.size), kinds, labels))
    starts = np.zeros((count, 3), np.intp)
    flat = per_kind.ravel()
    starts.ravel()[:] = np.concatenate([[0], np.cumsum(flat)[:-1]])
    classes = []
    signature = per_kind @ np.array([1, 1 << 20, 1 << 40], np.int64)
    for sig in np.unique(signature):
        members = np.flatnonzero(signature == sig)
        index = []
        for kind in range(3):
            size = int(per_kind[members[0], kind])
            chosen = order[
                (starts[members, kind][:, None] + np.arange(size)[None, :]).ravel()
            ].reshape(len(members), size)
            index.append(chosen - offsets[kind])
        classes.append(_Groups(*index))
    return classes


def _blocks(matrix: sparse.csr_matrix, rows: IndexArray, cols: IndexArray) -> FloatArray:
    """Return the dense blocks ``matrix[rows[g]][:, cols[g]]`` of every group, (g, r, c)."""
    out = np.zeros((rows.shape[0], rows.shape[1], cols.shape[1]))
    if rows.shape[1] == 0 or cols.shape[1] == 0:
        return out
    sub = sparse.csr_matrix(matrix[rows.ravel()]).tocoo()
    group, row_local = np.divmod(sub.row, rows.shape[1])
    # Column j of the matrix belongs to one group only: find its slot in this group's list.
    slot = np.full(matrix.shape[1], -1, np.intp)
    slot[cols.ravel()] = np.tile(np.arange(cols.shape[1]), cols.shape[0])
    owner = np.full(matrix.shape[1], -1, np.intp)
    owner[cols.ravel()] = np.repeat(np.arange(cols.shape[0]), cols.shape[1])
    keep = owner[sub.col] == group
    out[group[keep], row_local[keep], slot[sub.col[keep]]] = sub.data[keep]
    return out


def _scatter(
    parts: list[tuple[IndexArray, IndexArray, FloatArray]], shape: tuple[int, int]
) -> sparse.csr_matrix:
    """Assemble a sparse matrix from dense blocks at (rows[g], cols[g])."""
    if not parts:
        return sparse.csr_matrix(shape)
    rows, cols, data = [], [], []
    for r, c, block in parts:
        rows.append(np.broadcast_to(r[:, :, None], block.shape).ravel())
        cols.append(np.broadcast_to(c[:, None, :], block.shape).ravel())
        data.append(block.ravel())
    return sparse.csr_matrix(
        (np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))), shape=shape
    )
