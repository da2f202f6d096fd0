"""Sparse selection of library terms, scored on held-out blocks.

Forward selection with orthogonal refits (as orthogonal matching pursuit, but the next term
is the one whose joint refit on the *training* rows predicts the *held-out* rows best, not
the one most correlated with the training residual): a term is added only when it lowers the
same Bayesian information criterion the registry search uses (effective held-out count,
:func:`es_calibration.search.state.information_delta`) and cuts the held-out RMS by at least
``MIN_RELATIVE_GAIN``. Everything runs on the Gram matrices of the (scaled) columns and the
residual, accumulated once per row set, so a candidate costs a k x k solve, not a pass over
the samples.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from es_calibration.search.state import MIN_RELATIVE_GAIN, information_delta
from es_common.arrays import FloatArray

#: Most terms the step selects (the parameters file carries as many).
MAX_TERMS: Final = 3
#: A term is stable when its coefficient on each half of the record lies within this
#: fraction of its whole-record value (same sign).
STABILITY: Final = 0.5
#: Relative ridge on the Gram diagonal (keeps nearly collinear candidates solvable).
RIDGE: Final = 1e-9


@dataclass
class Gram:
    """X'X, X'r and r'r of one row set (X: scaled library columns, r: the residual)."""

    xx: FloatArray
    xr: FloatArray
    rr: float
    count: int

    @classmethod
    def empty(cls, p: int) -> Gram:
        """Return a zero Gram of ``p`` columns."""
        return cls(np.zeros((p, p)), np.zeros(p), 0.0, 0)

    def add(self, x: FloatArray, r: FloatArray) -> None:
        """Accumulate samples ``x`` (m, p) with residual ``r`` (m,)."""
        self.xx += x.T @ x
        self.xr += x.T @ r
        self.rr += float(r @ r)
        self.count += r.size

    def __add__(self, other: Gram) -> Gram:
        """Return the Gram of both row sets."""
        return Gram(self.xx + other.xx, self.xr + other.xr, self.rr + other.rr,
                    self.count + other.count)

    def solve(self, chosen: list[int]) -> FloatArray:
        """Return the least-squares coefficients of the columns ``chosen``."""
        idx = np.asarray(chosen, np.intp)
        a = self.xx[np.ix_(idx, idx)]
        a = a + RIDGE * np.trace(a) / max(idx.size, 1) * np.eye(idx.size)
        return np.asarray(np.linalg.solve(a, self.xr[idx]), np.float64)

    def sse(self, chosen: list[int], beta: FloatArray) -> float:
        """Return the sum of squared residuals of this set after ``beta`` on ``chosen``."""
        if not chosen:
            return self.rr
        idx = np.asarray(chosen, np.intp)
        value = self.rr - 2.0 * float(beta @ self.xr[idx])
        value += float(beta @ self.xx[np.ix_(idx, idx)] @ beta)
        return max(value, 0.0)


@dataclass
class Selection:
    """The chosen columns, their training coefficients and the held-out SSE after each."""

    chosen: list[int]
    beta: FloatArray
    sse_path: list[float]  # held-out SSE before any term, then after each added term


def select(train: Gram, held: Gram, n_effective: float,
           max_terms: int = MAX_TERMS, allowed: np.ndarray | None = None) -> Selection:
    """Forward-select columns fitted on ``train`` and scored on ``held`` (see module doc).

    ``allowed``: the columns that may be chosen (default: all).
    """
    chosen: list[int] = []
    beta = np.zeros(0)
    path = [held.rr]
    p = train.xr.size
    usable = np.diag(train.xx) > 0
    if allowed is not None:
        usable &= allowed
    while len(chosen) < max_terms:
        best: tuple[float, int, FloatArray] | None = None
        for j in range(p):
            if j in chosen or not usable[j]:
                continue
            trial = [*chosen, j]
            b = train.solve(trial)
            sse = held.sse(trial, b)
            if best is None or sse < best[0]:
                best = (sse, j, b)
        if best is None:
            break
        sse, j, b = best
        gain = 1.0 - np.sqrt(sse / max(path[-1], 1e-300))
        if information_delta(path[-1], sse, n_effective, 1) >= 0 or gain < MIN_RELATIVE_GAIN:
            break
        chosen, beta = [*chosen, j], b
        path.append(sse)
    return Selection(chosen, beta, path)


def scale_fit(column: FloatArray, residual: FloatArray) -> float:
    """Return the least-squares scale of ``column`` for ``residual`` (finite pairs; 0: none)."""
    c, r = np.ravel(column), np.ravel(residual)
    ok = np.isfinite(c) & np.isfinite(r)
    denominator = float(c[ok] @ c[ok])
    return float(c[ok] @ r[ok]) / denominator if denominator > 0 else 0.0


def stable(full: float, halves: tuple[float, float]) -> bool:
    """Return whether both halves' coefficients lie within STABILITY of ``full``."""
    return full != 0.0 and all(abs(h - full) <= STABILITY * abs(full) for h in halves)
