"""Whether an effect stands in for a constant offset of each actuator's displacement.

The law has no constant term: a displacement that is offset by a constant (an
interferometer's zero, an expansion whose zero lies outside the record) is taken up by
whatever candidate can shift the mean of the prediction, e.g. the coupling's neighbour sum,
which is always positive. Such a stand-in holds on both halves of the record (a constant is
the same in each), so :mod:`.halves` cannot catch it. Here the candidate's model is refitted
with a free offset per actuator, eliminated exactly by centring the prediction, the
Jacobians and the measured displacement over each actuator's valid training samples
(variable projection): a real effect keeps its parameters; one that moves (the rule of
:func:`.agreement.disagreement`) was fitted to the offset.

An effect whose own unknowns include a constant (``thermal_expansion``'s offset) loses
nothing: that column centres to zero, the ridge holds it at its value and its uncertainty
becomes unbounded, so it never counts as moved.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from es_calibration.data.align import AlignedData
from es_calibration.model.composite import Evaluation, FitInputs
from es_calibration.model.fit import levenberg_marquardt
from es_calibration.search.agreement import NotANumberError, disagreement
from es_calibration.search.state import ModelState, fitted_effect
from es_common.arrays import BoolArray, FloatArray
from es_physics.effects import get


def _centred(values: FloatArray, weights: FloatArray, count: FloatArray) -> FloatArray:
    """Return ``values`` (A, n, ...) minus their mean over each actuator's weighted samples."""
    shape = (values.shape[0], 1, *values.shape[2:])
    w = weights.reshape(weights.shape + (1,) * (values.ndim - 2))
    mean = np.sum(values * w, axis=1).reshape(shape) / count.reshape(
        (-1,) + (1,) * (values.ndim - 1)
    )
    return np.asarray(values - mean, np.float64)


def _with_offsets(ev: Evaluation, valid: BoolArray) -> Evaluation:
    """Return ``ev`` with each actuator's mean over ``valid`` taken out (the free offset)."""
    weights = valid.astype(np.float64)
    count = np.maximum(weights.sum(axis=1), 1.0)
    jac_local = ev.jac_local if ev.jac_local.size == 0 else _centred(ev.jac_local, weights, count)
    jac_global = (
        ev.jac_global if ev.jac_global.size == 0 else _centred(ev.jac_global, weights, count)
    )
    return Evaluation(_centred(ev.prediction, weights, count), jac_local, jac_global)


def refit_with_offsets(state: ModelState, train: FitInputs) -> ModelState:
    """Return ``state``'s model refitted on ``train`` with a free offset per actuator."""
    valid = train.valid
    weights = valid.astype(np.float64)
    count = np.maximum(weights.sum(axis=1), 1.0)
    target = np.where(valid, _centred(train.displacement, weights, count), 0.0)
    model = state.model
    result = levenberg_marquardt(
        lambda loc, glo, jac: _with_offsets(model.evaluate(loc, glo, train, jac), valid),
        target,
        valid,
        state.fit.local,
        state.fit.glob,
    )
    return replace(state, fit=result)


def offset_stand_in(
    state: ModelState, name: str, train: FitInputs, aligned: AlignedData
) -> str | None:
    """Return why effect ``name`` of ``state`` stood in for constant offsets, or None."""
    effect = get(name)
    with_offsets = refit_with_offsets(state, train)
    fits = [fitted_effect(s, effect, aligned) for s in (state, with_offsets)]
    values = [effect.reported(f) for f in fits]
    sigmas = [effect.uncertainties(f) for f in fits]
    try:
        moved = disagreement(values, sigmas)
    except NotANumberError as bad:  # as on a half (halves.py): never a crash of the search
        return f"{bad} not a number once each actuator may carry a constant offset"
    if moved is None:
        return None
    key, before, after, combined = moved
    return (
        f"{key} goes from {before:.3g} to {after:.3g} (1-sigma {combined:.2g}) once each "
        "actuator may carry a constant offset: it stood in for one"
    )
