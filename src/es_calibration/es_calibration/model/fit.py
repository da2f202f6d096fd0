"""Batched Levenberg-Marquardt for many actuators with parameters shared by all of them.

Each actuator a has its own small parameter vector p_a (the law coefficients) and all share a
global vector g (the effect parameters). The Gauss-Newton normal equations then have an arrow
shape: a block-diagonal part (one P x P block per actuator), a G x G global part and their
coupling. The global step is solved on the Schur complement and each actuator's step with
numpy's batched ``linalg.solve``, so the cost is linear in the number of actuators and there is
no Python loop over them. Without global parameters every actuator keeps its own damping.

Parameters are Jacobi-scaled by the first iteration's Jacobian column norms, and a weak ridge
(``ridge``, relative to that scale) pulls each parameter towards its prior value: directions
the data do not determine (e.g. the temperature slope when the temperature never changes) stay
at the prior instead of wandering off. Covariances are s^2 (J^T J)^-1 with s^2 the residual
variance, inflated by ``variance_inflation`` (residual autocorrelation, see residual.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from es_calibration.model.composite import Evaluation
from es_common.arrays import BoolArray, FloatArray


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`levenberg_marquardt`.

    Attributes:
        local: per-actuator parameters (A, P).
        glob: global parameters (G,).
        cost: per-actuator sum of squared residuals over valid samples (A,) [m^2].
        count: per-actuator number of valid samples (A,).
        cov_local: per-actuator covariance (A, P, P) (marginal over the globals).
        cov_global: covariance of the globals (G, G).
        iterations: iterations run.

    """

    local: FloatArray
    glob: FloatArray
    cost: FloatArray
    count: FloatArray
    cov_local: FloatArray
    cov_global: FloatArray
    iterations: int

    @property
    def total_cost(self) -> float:
        """Return the summed cost over all actuators."""
        return float(self.cost.sum())


#: (local (A, P), glob (G,), with Jacobians?) -> Evaluation
Evaluate = Callable[[FloatArray, FloatArray, bool], Evaluation]
#: Rejected steps in a row after which the fit counts as converged. Each one raises the
#: damping tenfold: after three (damping ~1 on the scaled system) a fit whose Jacobian is
#: approximate (the per-actuator law's columns under a neighbour coupling) or strongly
#: nonlinear (a drift started far from its time constant) stopped where it started; after
#: eight the step is a short gradient step, and a stall there is convergence.
MAX_STALLS = 8


def pooled_gram(columns: FloatArray, resid: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return the sums over (a, n) of c c' (K, K) and c r (K,): columns (A, n, K), resid (A, n).

    One matrix product over the flattened (actuator, sample) pairs, BLAS on one thread (see
    calibrate.py): a (64 x 3000, 28) gram took 13 ms, ``np.einsum`` of the same sums (an
    unblocked loop) 87-93 ms. The sums are the same up to rounding (their order differs).
    """
    pairs = columns.shape[0] * columns.shape[1]
    flat = np.ascontiguousarray(columns).reshape(pairs, columns.shape[-1])
    return flat.T @ flat, flat.T @ np.ascontiguousarray(resid).reshape(pairs)


def _normal_equations(
    ev: Evaluation, target: FloatArray, valid: BoolArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Return U, W, Vg, bl, bg and the per-actuator cost (the Jacobians are masked in place)."""
    resid = np.where(valid, target - ev.prediction, 0.0)
    jl = ev.jac_local
    jg = ev.jac_global
    invalid = ~valid
    if invalid.any():
        jl[invalid] = 0.0
        jg[invalid] = 0.0
    jlt = np.swapaxes(jl, 1, 2)
    U = jlt @ jl
    W = jlt @ jg
    Vg, bg = pooled_gram(jg, resid)
    bl = (jlt @ resid[..., None])[..., 0]
    cost = np.einsum("an,an->a", resid, resid)
    return U, W, Vg, bl, bg, cost


def _cost(ev: Evaluation, target: FloatArray, valid: BoolArray) -> FloatArray:
    resid = np.where(valid, target - ev.prediction, 0.0)
    return np.asarray(np.einsum("an,an->a", resid, resid), np.float64)


def _solve_step(
    U: FloatArray,
    W: FloatArray,
    Vg: FloatArray,
    bl: FloatArray,
    bg: FloatArray,
    *,
    damping_local: FloatArray,
    damping_global: float,
) -> tuple[FloatArray, FloatArray]:
    """Solve the (scaled, damped) arrow system; return the local (A, P) and global (G,) steps."""
    P = U.shape[1]
    G = Vg.shape[0]
    eye = np.eye(P)
    Ud = U + damping_local[:, None, None] * eye
    Ud_inv_bl = np.linalg.solve(Ud, bl[..., None])[..., 0]
    if G == 0:
        return np.asarray(Ud_inv_bl, np.float64), np.zeros(0)
    Ud_inv_W = np.linalg.solve(Ud, W)
    S = Vg + damping_global * np.eye(G) - np.einsum("apg,aph->gh", W, Ud_inv_W)
    rhs = bg - np.einsum("apg,ap->g", W, Ud_inv_bl)
    dg = np.linalg.solve(S, rhs)
    dl = Ud_inv_bl - Ud_inv_W @ dg
    return np.asarray(dl, np.float64), np.asarray(dg, np.float64)


def levenberg_marquardt(
    evaluate: Evaluate,
    target: FloatArray,
    valid: BoolArray,
    local0: FloatArray,
    glob0: FloatArray,
    *,
    max_iter: int = 40,
    ridge: float = 1e-8,
    rel_tol: float = 1e-8,
    variance_inflation: float = 1.0,
) -> FitResult:
    """Minimise the summed squared residual ``target - prediction`` over valid samples.

    Args:
        evaluate: (local (A, P), glob (G,)) -> :class:`Evaluation`.
        target: measured values (A, n).
        valid: samples that count (A, n).
        local0: starting and prior per-actuator parameters (A, P).
        glob0: starting and prior global parameters (G,).
        max_iter: iteration limit.
        ridge: weight of the pull towards the prior, relative to each parameter's data weight.
        rel_tol: stop when the relative cost decrease falls below this.
        variance_inflation: factor applied to the covariances (>= 1).

    """
    local = np.array(local0, np.float64)
    glob = np.array(glob0, np.float64)
    prior_l, prior_g = local.copy(), glob.copy()
    A, P = local.shape
    G = glob.size
    ev = evaluate(local, glob, True)
    U, W, Vg, bl, bg, cost = _normal_equations(ev, target, valid)
    sl = np.sqrt(np.maximum(np.einsum("app->ap", U), 1e-300))
    sg = np.sqrt(np.maximum(np.diag(Vg), 1e-300))
    lam_l = np.full(A, 1e-3)
    lam_g = 1e-3
    iterations = 0
    stalls = 0

    def penalised(cost_a: FloatArray, loc: FloatArray, gl: FloatArray) -> FloatArray:
        pen = ridge * np.sum(((loc - prior_l) * sl) ** 2, axis=1)
        return np.asarray(cost_a + pen + ridge * np.sum(((gl - prior_g) * sg) ** 2) / A)

    current = penalised(cost, local, glob)
    for iterations in range(1, max_iter + 1):  # noqa: B007 - the count is reported
        # scaled system: x_s = x * s; ridge pulls towards the prior
        Us = U / (sl[:, :, None] * sl[:, None, :])
        Ws = W / (sl[:, :, None] * sg[None, None, :]) if G else W
        Vs = Vg / np.outer(sg, sg) if G else Vg
        bls = bl / sl - ridge * (local - prior_l) * sl
        bgs = bg / sg - ridge * (glob - prior_g) * sg if G else bg
        dl_s, dg_s = _solve_step(
            Us + ridge * np.eye(P),
            Ws,
            Vs + ridge * np.eye(G),
            bls,
            bgs,
            damping_local=lam_l,
            damping_global=lam_g,
        )
        new_local = local + dl_s / sl
        new_glob = glob + dg_s / sg if G else glob
        new_ev = evaluate(new_local, new_glob, False)
        new_cost = _cost(new_ev, target, valid)
        ok_values = np.isfinite(new_cost)
        trial = np.where(
            ok_values, penalised(np.where(ok_values, new_cost, 0.0), new_local, new_glob), np.inf
        )
        before = current.sum()
        if G == 0:
            better = trial < current
            local = np.where(better[:, None], new_local, local)
            lam_l = np.where(better, lam_l * 0.3, lam_l * 10.0)
            improved = bool(better.any())
        else:
            improved = bool(trial.sum() < before)
            if improved:
                local, glob = new_local, new_glob
            lam_g = lam_g * 0.3 if improved else lam_g * 10.0
            lam_l = np.full(A, lam_g)
        if not improved:
            stalls += 1
            if stalls >= MAX_STALLS:
                break
            continue
        stalls = 0
        ev = evaluate(local, glob, True)
        U, W, Vg, bl, bg, cost = _normal_equations(ev, target, valid)
        current = penalised(cost, local, glob)
        if (before - current.sum()) / max(before, 1e-300) < rel_tol:
            break

    count = valid.sum(axis=1).astype(np.float64)
    dof = max(float(count.sum()) - A * P - G, 1.0)
    s2_local = cost / np.maximum(count - P, 1.0) * variance_inflation
    s2_pooled = float(cost.sum()) / dof * variance_inflation
    Us = U / (sl[:, :, None] * sl[:, None, :]) + ridge * np.eye(P)
    Ui = np.linalg.inv(Us)
    if G:
        Ws = W / (sl[:, :, None] * sg[None, None, :])
        S = Vg / np.outer(sg, sg) + ridge * np.eye(G) - np.einsum("apg,aph->gh", Ws, Ui @ Ws)
        Si = np.linalg.inv(S)
        UiW = Ui @ Ws
        Ui = Ui + UiW @ Si @ np.swapaxes(UiW, 1, 2)
        cov_g = Si / np.outer(sg, sg) * s2_pooled
    else:
        cov_g = np.zeros((0, 0))
    cov_l = Ui / (sl[:, :, None] * sl[:, None, :]) * s2_local[:, None, None]
    return FitResult(local, glob, cost, count, cov_l, cov_g, iterations)
