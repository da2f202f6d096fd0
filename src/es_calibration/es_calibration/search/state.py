"""Fitted model states and the workspace of one calibration run (rows, inputs, caches).

Candidates are screened on a contiguous block of at most ``SCREEN_SIZE`` x ``SCREEN_SIZE``
actuators at the grid's corner (edges and interior; the coupling needs neighbours); the
accepted model is then refitted on the whole grid in actuator tiles (:mod:`..grid.tiles`). How each
candidate is fitted: :mod:`.scans`; which are kept: :mod:`.selection`.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from es_calibration.data.align import AlignedData, select_rows
from es_calibration.model.cache import BoundedCache, cache_bypassed, rows_key
from es_calibration.model.composite import CompositeModel, FitInputs, play_operator
from es_calibration.model.fit import FitResult, levenberg_marquardt
from es_calibration.model.history import DriveHistory, DriveSamples
from es_calibration.search.residual import integrated_autocorrelation_time
from es_common.arrays import BoolArray, FloatArray, IndexArray
from es_physics.effects import Effect, FittedEffect, Role, get
from es_physics.params import ActuatorParams

SCREEN_SIZE: Final = 8
#: Samples per actuator used for fits and held-out scores (capped by sample-actuator totals).
FIT_SAMPLES: Final = 6000
FIT_BUDGET: Final = 2_000_000
SCORE_SAMPLES: Final = 20000
SCORE_BUDGET: Final = 3_000_000
#: Smallest relative cut of the held-out RMS that counts as an improvement (an effect, an
#: operator, a stamp convention).
MIN_RELATIVE_GAIN: Final = 0.01


@dataclass
class ModelState:
    """A fitted composite model on a set of actuators."""

    model: CompositeModel
    delay_s: float
    thresholds: tuple[float, ...]
    fit: FitResult
    heldout_sse: float = 0.0
    heldout_count: int = 0

    @property
    def heldout_rms(self) -> float:
        """Return the held-out RMS error [m]."""
        return float(np.sqrt(self.heldout_sse / max(self.heldout_count, 1)))

    @property
    def play_thresholds(self) -> tuple[float, ...] | None:
        """Return the play thresholds [V] when the model has a play effect, else None."""
        return self.thresholds if self.model.play else None


#: Drive histories by recording (id of its command array, dropped with it) and actuators:
#: every workspace on the same record (the search's, the halves', the other stamp
#: convention's, the discovery's) filters it once.
_HISTORIES: dict[int, dict[tuple[bytes, float], DriveHistory]] = {}


def shared_history(aligned: AlignedData, actuators: IndexArray) -> DriveHistory:
    """Return the drive history of ``actuators`` of ``aligned``'s command, one per recording.

    Kept while the command array lives; a new one each time inside
    :func:`es_calibration.model.cache.bypassed`.
    """
    command = aligned.command
    if cache_bypassed():
        return DriveHistory(command[:, actuators], aligned.command_period)
    key = (np.ascontiguousarray(actuators, np.intp).tobytes(), float(aligned.command_period))
    if id(command) not in _HISTORIES:
        _HISTORIES[id(command)] = {}
        weakref.finalize(command, _HISTORIES.pop, id(command), None)
    per_record = _HISTORIES[id(command)]
    if key not in per_record:
        per_record[key] = DriveHistory(command[:, actuators], aligned.command_period)
    return per_record[key]


class Workspace:
    """Rows, actuators and cached inputs of one calibration run."""

    def __init__(self, aligned: AlignedData, actuators: IndexArray, grid: tuple[int, int]):
        """Select fit and score rows for ``actuators`` (a row-major block of shape ``grid``)."""
        self.aligned = aligned
        self.actuators = actuators
        self.grid = grid
        A = len(actuators)
        n_fit = int(min(FIT_SAMPLES, max(1000, FIT_BUDGET // A)))
        n_score = int(min(SCORE_SAMPLES, max(1000, SCORE_BUDGET // A)))
        self.fit_rows = select_rows(aligned.train, n_fit)
        self.score_rows = select_rows(~aligned.train, n_score)
        #: play operators by (threshold, delay) at the fit and score rows, and by
        #: (threshold, command rows) at any other rows (the NNLS screening's)
        self._play: BoundedCache[FloatArray] = BoundedCache()
        self._play_rows: BoundedCache[FloatArray] = BoundedCache()
        self._static_cache: dict[tuple[int, int], dict[str, npt.NDArray[Any]]] = {}
        self._history: DriveHistory | None = None
        self._sub_rows: dict[int, IndexArray] = {}
        self._travel: FloatArray | None = None

    @property
    def history(self) -> DriveHistory:
        """The actuators' command history (built on first use: only drive filters need it)."""
        if self._history is None:
            self._history = shared_history(self.aligned, self.actuators)
        return self._history

    def sub_rows(self, stride: int) -> IndexArray:
        """Return every ``stride``-th training row (the same array for the same stride)."""
        if stride not in self._sub_rows:
            self._sub_rows[stride] = self.fit_rows[::stride]
        return self._sub_rows[stride]

    def _command_rows(self, delay_s: float) -> tuple[IndexArray, IndexArray]:
        a = self.aligned
        return a.command_index(self.fit_rows, delay_s), a.command_index(self.score_rows, delay_s)

    def play(self, thresholds: Sequence[float], command_rows: IndexArray) -> FloatArray:
        """Return the play of the command (len(rows), len(thresholds), A) at ``command_rows``.

        NaN until the operator's state no longer depends on its unknown state at the start
        of the data: once the command has moved over 2 r (then every start state has met the
        command's edge). An actuator whose command never does so keeps the start convention
        of :func:`play_operator`.
        """
        keep = np.unique(np.maximum(command_rows, 0))
        r = np.asarray(thresholds, np.float64)[:, None]
        command = self.aligned.command[:, self.actuators]
        values = play_operator(command, r, keep)
        if self._travel is None:
            self._travel = np.maximum.accumulate(command, axis=0) - np.minimum.accumulate(
                command, axis=0
            )
        moved = self._travel[:, None, :] >= 2.0 * r[None]  # (N, K, A)
        settle = np.where(moved.any(axis=0), np.argmax(moved, axis=0), 0)  # (K, A)
        values[keep[:, None, None] < settle[None]] = np.nan
        return values[np.searchsorted(keep, np.maximum(command_rows, 0))]

    def cached_play(self, thresholds: Sequence[float], command_rows: IndexArray) -> FloatArray:
        """Return :meth:`play` (len(rows), len(thresholds), A), cached by threshold and rows.

        The NNLS screening reads the play of many thresholds at the same subsampled rows in
        every round, zoom and refit: one pass over the command for all thresholds not
        computed before at these rows.
        """
        rows = rows_key(command_rows)
        found: dict[float, FloatArray] = {}
        for r in dict.fromkeys(float(v) for v in thresholds):
            if (value := self._play_rows.get((r, rows))) is not None:
                found[r] = value
        todo = [r for r in dict.fromkeys(float(v) for v in thresholds) if r not in found]
        if todo:
            values = self.play(todo, command_rows)
            for i, r in enumerate(todo):
                found[r] = self._play_rows.put((r, rows), values[:, i, :].copy())
        return np.stack([found[float(r)] for r in thresholds], axis=1)

    def play_pair(
        self, thresholds: Sequence[float], delay_s: float
    ) -> tuple[FloatArray, FloatArray]:
        """Return the play (rows, thresholds, A) at the fit and score rows.

        One pass over the command for all thresholds not computed before (cached by threshold
        and delay: the play loop over time is the slowest step of the search).
        """
        fit_ci, score_ci = self._command_rows(delay_s)
        found: dict[float, FloatArray] = {}
        for r in dict.fromkeys(float(v) for v in thresholds):
            if (value := self._play.get((r, delay_s))) is not None:
                found[r] = value
        todo = [r for r in dict.fromkeys(float(v) for v in thresholds) if r not in found]
        if todo:
            both = self.play(todo, np.concatenate([fit_ci, score_ci]))
            for i, r in enumerate(todo):
                found[r] = self._play.put((r, delay_s), both[:, i, :].copy())
        stacked = np.stack([found[float(r)] for r in thresholds], axis=1)
        return stacked[: fit_ci.size], stacked[fit_ci.size :]

    def _static(self, rows: IndexArray) -> dict[str, npt.NDArray[Any]]:
        """Return the delay-independent inputs at ``rows`` (cached per row set)."""
        key = (id(rows), rows.size)
        if key not in self._static_cache:
            a = self.aligned
            act = self.actuators
            z = a.displacement[np.ix_(rows, act)].T
            # an actuator's own unresolvable command edges take out its pairs (edges.py)
            usable = np.isfinite(z) & ~a.edge_excluded(rows, act)
            self._static_cache[key] = {
                "t": a.t[rows],
                "temperature": a.temperature_at(rows, act),
                "temperature_rate": a.temperature_rate_at(rows, act),
                "displacement": z,
                "finite": usable,
            }
        return self._static_cache[key]

    def split_delay(self, delay_s: float) -> tuple[float, float]:
        """Return (whole command periods [s], fraction of a period) of a delay."""
        period = self.aligned.command_period
        periods = delay_s / period
        whole = float(np.floor(periods + 1e-9))
        return whole * period, max(periods - whole, 0.0)

    def inputs(self, rows: IndexArray, delay_s: float, play: FloatArray | None) -> FitInputs:
        """Return model inputs at ``rows`` with the command ``delay_s`` earlier.

        ``play`` holds the play operators at ``rows``, (len(rows), K, A), or is None.

        A delay of j + f command periods gives the command interpolated at f between the ones
        in effect j and j + 1 periods earlier (fractional delay), with the cubic convolution
        kernel (Keys, a = -1/2) over the commands j - 1 .. j + 2: a drive sampled at ten
        samples a period of its fastest tone is then reproduced to ~0.1 % (linear
        interpolation: ~5 %, and a bias of the delay towards whole periods).
        """
        a = self.aligned
        static = self._static(rows)
        whole_s, frac = self.split_delay(delay_s)
        shifts = [(whole_s, 1.0)]
        if frac > 1e-9:
            f, T = frac, a.command_period
            shifts = [
                (whole_s - T, (-(f**3) + 2 * f**2 - f) / 2),
                (whole_s, (3 * f**3 - 5 * f**2 + 2) / 2),
                (whole_s + T, (-3 * f**3 + 4 * f**2 + f) / 2),
                (whole_s + 2 * T, (f**3 - f**2) / 2),
            ]
        voltage: FloatArray = np.zeros(static["displacement"].shape)
        valid: BoolArray = np.array(static["finite"], dtype=bool)
        taps = []
        for shift, weight in shifts:
            ci = a.command_index(rows, shift)
            taps.append((np.maximum(ci, 0), weight))
            u = a.command[np.ix_(np.maximum(ci, 0), self.actuators)].T
            valid &= np.isfinite(u) & (ci >= 0)[None, :]
            if not a.command_finite_all:
                valid &= a.command_finite[np.ix_(np.maximum(ci, 0), self.actuators)].T
            voltage = np.asarray(voltage + weight * u, np.float64)
        operators = None
        if play is not None:
            operators = np.ascontiguousarray(play.transpose(1, 2, 0))
            settled = np.isfinite(operators).all(axis=0)
            if not settled.all():  # a play state not yet known (see play()): left out
                valid &= settled
                operators = np.where(np.isfinite(operators), operators, 0.0)
        return FitInputs(
            t=static["t"],
            voltage=voltage,
            play=operators,
            temperature=static["temperature"],
            temperature_rate=static["temperature_rate"],
            displacement=np.where(valid, static["displacement"], 0.0),
            valid=valid,
            grid=self.grid,
            mean_temperature=a.mean_temperature,
            drive=DriveSamples(self.history, tuple(taps)),
        )

    def input_pair(
        self, delay_s: float, thresholds: Sequence[float] | None
    ) -> tuple[FitInputs, FitInputs]:
        """Return (training, held-out) inputs for a delay and optional play thresholds."""
        fit_play = score_play = None
        if thresholds is not None:
            fit_play, score_play = self.play_pair(thresholds, delay_s)
        return (
            self.inputs(self.fit_rows, delay_s, fit_play),
            self.inputs(self.score_rows, delay_s, score_play),
        )


def initial_law(inputs: FitInputs, base: ActuatorParams | None = None) -> FloatArray:
    """Return starting law coefficients (A, 4): the thesis law scaled to each actuator's gain."""
    base = base or ActuatorParams()
    model = CompositeModel(())
    A = inputs.voltage.shape[0]
    local = np.tile([base.m2, base.m1, base.k2, base.k1], (A, 1)).astype(np.float64)
    H = model.evaluate(local, np.zeros(0), inputs, jacobian=False).prediction
    w = inputs.valid
    num = np.sum(np.where(w, H * inputs.displacement, 0.0), axis=1)
    den = np.sum(np.where(w, H * H, 0.0), axis=1)
    gain = np.where(den > 0, num / np.maximum(den, 1e-300), 1.0)
    gain = np.where(gain > 0.05, gain, 1.0)
    local[:, :2] *= gain[:, None]
    return local


def fit_state(
    model: CompositeModel,
    train: FitInputs,
    heldout: FitInputs,
    local0: FloatArray,
    glob0: FloatArray,
    *,
    delay_s: float,
    thresholds: tuple[float, ...],
    inflation: float = 1.0,
    max_iter: int = 40,
) -> ModelState:
    """Fit ``model`` on ``train`` from the given start and score it on ``heldout``."""
    result = levenberg_marquardt(
        lambda loc, glo, jac: model.evaluate(loc, glo, train, jac),
        train.displacement,
        train.valid,
        local0,
        glob0,
        variance_inflation=inflation,
        max_iter=max_iter,
    )
    pred = model.evaluate(result.local, result.glob, heldout, jacobian=False).prediction
    resid = np.where(heldout.valid, heldout.displacement - pred, 0.0)
    return ModelState(
        model,
        delay_s,
        thresholds,
        result,
        float(np.sum(resid * resid)),
        int(heldout.valid.sum()),
    )


def refit_state(state: ModelState, train: FitInputs, heldout: FitInputs) -> ModelState:
    """Return ``state``'s model refitted on ``train`` from its values, scored on ``heldout``.

    The delay and play thresholds stay as found (e.g. the data moved by discovered terms).
    """
    return fit_state(state.model, train, heldout, state.fit.local, state.fit.glob,
                     delay_s=state.delay_s, thresholds=state.thresholds)


def information_delta(
    sse_before: float, sse_after: float, n_effective: float, n_added: int
) -> float:
    """Return the BIC change of adding ``n_added`` parameters (negative favours the addition)."""
    n = max(n_effective, 2.0)
    return float(n * np.log(max(sse_after, 1e-300) / max(sse_before, 1e-300)) + n_added * np.log(n))


def effective_count(ws: Workspace, state: ModelState, heldout: FitInputs) -> float:
    """Return the number of independent held-out residuals of ``state`` on the score rows."""
    resid = heldout_residual(state, heldout)
    stride = max(1, int(np.median(np.diff(ws.score_rows))))
    tau = integrated_autocorrelation_time(resid, contiguous=np.diff(ws.score_rows) == stride)
    return float(state.heldout_count / max(tau, 1.0))


def heldout_residual(state: ModelState, heldout: FitInputs) -> FloatArray:
    """Return the held-out residual (A, n), NaN where invalid."""
    pred = state.model.evaluate(state.fit.local, state.fit.glob, heldout, jacobian=False).prediction
    return np.where(heldout.valid, heldout.displacement - pred, np.nan)


def extend_local(state: ModelState, model: CompositeModel) -> FloatArray:
    """Return ``model``'s local start from ``state`` (see :func:`local_start`)."""
    return local_start(state.model.local_names, state.fit.local, model, state)


def local_start(
    names: Sequence[str], local: FloatArray, model: CompositeModel, values: ModelState
) -> FloatArray:
    """Return ``model``'s local start (A, P) from ``local`` (A, len(names)).

    A per-actuator unknown missing from ``names`` starts at ``values``' grid value of it (its
    shared value, or the median of its per-actuator ones); any other (e.g. the curvature
    terms) at 0.
    """
    have = dict(zip(names, local.T, strict=True))
    grid: dict[str, float] = dict(zip(values.model.global_names, values.fit.glob, strict=True))
    for j, name in enumerate(values.model.local_names):
        grid.setdefault(name, float(np.median(values.fit.local[:, j])))
    A = local.shape[0]
    columns = [
        have[n] if n in have else np.full(A, grid.get(n, 0.0) if n in model.per_actuator else 0.0)
        for n in model.local_names
    ]
    return np.stack(columns, axis=1)


def extend_global(state: ModelState, model: CompositeModel, new: dict[str, float]) -> FloatArray:
    """Return ``model``'s global start: ``state``'s values, else ``new``'s, else 0."""
    old = dict(zip(state.model.global_names, state.fit.glob, strict=True))
    return np.array([old.get(n, new.get(n, 0.0)) for n in model.global_names], np.float64)


def fitted_effect(state: ModelState, effect: Effect, aligned: AlignedData) -> FittedEffect:
    """Return ``effect``'s unknowns in ``state`` in the effect's own parameter names."""
    model = state.model
    sig_g = np.sqrt(np.maximum(np.diag(state.fit.cov_global), 0.0))
    values: dict[str, float] = {}
    sigma: dict[str, float] = {}
    local: dict[str, FloatArray] = {}
    local_sigma: dict[str, FloatArray] = {}
    for i, p in enumerate(model.parameter_names(effect)):
        key = model.key(effect, i)
        if key in model.per_actuator:
            # one value per actuator: the grid's median stands for them in the report
            j = model.local_names.index(key)
            local[p] = state.fit.local[:, j]
            local_sigma[p] = np.sqrt(np.maximum(state.fit.cov_local[:, j, j], 0.0))
            values[p], sigma[p] = float(np.median(local[p])), float(np.median(local_sigma[p]))
            continue
        j = model.global_names.index(key)
        values[p], sigma[p] = float(state.fit.glob[j]), float(sig_g[j])
    # with equal command and displacement stamps and the command not yet in effect at its own
    # stamp, a shift of d is a delay of d + one command period from the command's stamp
    late = aligned.has_same_stamps and not aligned.include_same_stamp
    offset = aligned.command_period if late else 0.0
    order = model.operators if effect is model.play else 1
    scanned = {Role.INPUT_SHIFT: (state.delay_s + offset,), Role.PLAY: state.thresholds}
    for p, value in zip(effect.searched_names(order), scanned.get(effect.role, ()), strict=True):
        values[p] = value
    for p in effect.local_parameters:
        j = model.local_names.index(p)
        local[p] = state.fit.local[:, j]
        local_sigma[p] = np.sqrt(np.maximum(state.fit.cov_local[:, j, j], 0.0))
    return FittedEffect(
        values, sigma, local, local_sigma, aligned.command_period, aligned.mean_temperature
    )


def undetermined(state: ModelState, name: str) -> str | None:
    """Return why ``state``'s fit leaves effect ``name`` undetermined (see the effect), or None."""
    model = state.model
    effect = get(name)
    sig_g = np.sqrt(np.maximum(np.diag(state.fit.cov_global), 0.0))
    values: dict[str, float] = {}
    sigma: dict[str, float] = {}
    for i, p in enumerate(model.parameter_names(effect)):
        key = model.key(effect, i)
        if key in model.global_names:
            j = model.global_names.index(key)
            values[p], sigma[p] = float(state.fit.glob[j]), float(sig_g[j])
    return effect.undetermined(FittedEffect(values, sigma))


def effect_parameters(state: ModelState, name: str, aligned: AlignedData) -> dict[str, float]:
    """Return the physical parameters of effect ``name`` in ``state``."""
    effect = get(name)
    return effect.reported(fitted_effect(state, effect, aligned))


def screen_block(grid: tuple[int, int]) -> tuple[IndexArray, tuple[int, int]]:
    """Return the actuator indices and shape of the screening block at the grid's corner."""
    rows = min(grid[0], SCREEN_SIZE)
    cols = min(grid[1], SCREEN_SIZE)
    idx = (np.arange(rows)[:, None] * grid[1] + np.arange(cols)[None, :]).ravel()
    return idx.astype(np.intp), (rows, cols)


def base_state(ws: Workspace) -> ModelState:
    """Fit the plain hyperbolic law (linear in T*) on the workspace's actuators."""
    train, held = ws.input_pair(0.0, None)
    model = CompositeModel(())
    return fit_state(
        model, train, held, initial_law(train), np.zeros(0), delay_s=0.0, thresholds=()
    )


def choose_stamp_convention(aligned: AlignedData) -> AlignedData:
    """Decide from the data whether a command stamped at a sample's own stamp is in effect.

    Only matters when command and displacement stamps coincide (lock-step recording): the
    convention with the smaller training cost of the plain law on the screening block wins.
    """
    if not aligned.has_same_stamps:
        return aligned
    idx, grid = screen_block(aligned.grid)
    costs = {}
    for include in (True, False):
        trial = replace(aligned, include_same_stamp=include)
        costs[include] = base_state(Workspace(trial, idx, grid)).fit.total_cost
    return replace(aligned, include_same_stamp=min(costs, key=lambda k: costs[k]))
