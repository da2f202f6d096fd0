"""The grid-wide refit in actuator tiles, each tile an independent task (serial or on Dask).

A tile is a block of at most ``tile`` x ``tile`` actuators; with the coupling (a ``SPATIAL``
effect) it is fitted with a one-actuator halo of its neighbours, whose results are dropped,
so that every kept actuator sees all its neighbours. Each tile is fitted on the samples of
the whole grid's refit (:func:`compact_grid`: the rows search.py's budgets choose for the
grid, gathered in one streamed pass), so a tile's per-actuator fit uses the same samples
whatever the tiling.

Shared (global) parameters: each tile fits them with its actuators (the same joint fit as
one tile covering the grid), and the tiles' estimates are combined by their information
(inverse covariance), g = (sum_k I_k)^-1 sum_k I_k g_k, the sufficient statistics of the
joint fit to first order (the Schur complements of the arrow-shaped normal equations add
over actuators, fit.py). Then, with more than one tile, every tile is refitted with the
combined values fixed, so that every actuator's law goes with the grid's shared values.
One tile covering the grid is the joint fit itself (no second pass). Covariances: per
actuator the tile fit's (marginal over the shared values), shared ones (sum_k I_k)^-1.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Final

import numpy as np

from es_feedforward.calibration.align import AlignedData, IndexArray
from es_feedforward.calibration.fit import FitResult, levenberg_marquardt
from es_feedforward.calibration.model import CompositeModel, Evaluation, FloatArray
from es_feedforward.calibration.recording import Gathered
from es_feedforward.calibration.search import ModelState, Workspace, initial_law

#: Default tile edge [actuators].
DEFAULT_TILE: Final = 16

#: Runs a function over jobs, in order: the serial ``map`` or a Dask client's.
TileMap = Callable[[Callable[["TileJob"], "TileFit"], Sequence["TileJob"]], list["TileFit"]]


class DaskSetupError(RuntimeError):
    """The Dask cluster for the tiles could not be started or reached (one-line message)."""


def serial_map(fn: Callable[[TileJob], TileFit], jobs: Sequence[TileJob]) -> list[TileFit]:
    """Run the tile jobs one after the other in this process."""
    return [fn(job) for job in jobs]


class TileWorkspace(Workspace):
    """A workspace on compact tile data whose play operators were streamed (recording.py)."""

    def __init__(self, aligned: AlignedData, play: dict[float, FloatArray]) -> None:
        """Use every row of ``aligned`` (already the grid's selection) and its play values."""
        super().__init__(aligned, np.arange(aligned.n_actuators, dtype=np.intp), aligned.grid)
        self.streamed_play = play

    def play(self, thresholds: Sequence[float], command_rows: IndexArray) -> FloatArray:
        """Return the streamed play (len(rows), len(thresholds), A) at ``command_rows``."""
        rows = np.maximum(command_rows, 0)
        return np.stack([self.streamed_play[float(r)][rows] for r in thresholds], axis=1)


@dataclass(frozen=True)
class TileJob:
    """One tile's fit: its compact data and where to start (all picklable, for Dask).

    ``core`` marks the tile's own actuators (the rest is halo); ``local0`` is None for the
    plain law's first fit (start from the thesis law scaled per actuator); ``fixed`` keeps
    ``glob0`` fixed.
    """

    aligned: AlignedData
    play: dict[float, FloatArray]
    core: np.ndarray
    effects: tuple[str, ...]
    operators: int
    delay_s: float
    thresholds: tuple[float, ...]
    local0: FloatArray | None
    glob0: FloatArray
    fixed: bool


@dataclass(frozen=True)
class TileFit:
    """A tile's fitted core actuators: per-actuator arrays (n_core, ...) and shared values."""

    local: FloatArray
    cov_local: FloatArray
    cost: FloatArray
    count: FloatArray
    heldout_sse: FloatArray
    heldout_count: FloatArray
    glob: FloatArray
    cov_global: FloatArray
    iterations: int


def fit_tile(job: TileJob) -> TileFit:
    """Fit one tile (module level, so a Dask worker can run it)."""
    model = CompositeModel(job.effects, operators=job.operators)
    ws = TileWorkspace(job.aligned, job.play)
    train, held = ws.input_pair(job.delay_s, job.thresholds if model.play else None)
    local0 = initial_law(train) if job.local0 is None else job.local0
    extra = len(model.local_names) - local0.shape[1]
    if extra > 0:  # a LAW effect's curvature terms start at zero
        local0 = np.concatenate([local0, np.zeros((local0.shape[0], extra))], axis=1)
    fixed = job.glob0

    def evaluate(loc: FloatArray, glob: FloatArray, jac: bool) -> Evaluation:
        ev = model.evaluate(loc, fixed if job.fixed else glob, train, jac)
        if job.fixed:
            return Evaluation(ev.prediction, ev.jac_local, ev.jac_global[..., :0])
        return ev

    result = levenberg_marquardt(
        evaluate,
        train.displacement,
        train.valid,
        local0,
        np.zeros(0) if job.fixed else job.glob0,
    )
    glob = fixed if job.fixed else result.glob
    pred = model.evaluate(result.local, glob, held, jacobian=False).prediction
    resid = np.where(held.valid, held.displacement - pred, 0.0)
    core = job.core
    return TileFit(
        local=result.local[core],
        cov_local=result.cov_local[core],
        cost=result.cost[core],
        count=result.count[core],
        heldout_sse=np.einsum("an,an->a", resid, resid)[core],
        heldout_count=held.valid.sum(axis=1)[core].astype(np.float64),
        glob=glob,
        cov_global=result.cov_global,
        iterations=result.iterations,
    )


@dataclass(frozen=True)
class Tile:
    """Actuators of one tile: all fitted (core + halo, row-major) and which are core."""

    actuators: IndexArray
    shape: tuple[int, int]
    core: np.ndarray
    core_actuators: IndexArray


def layout(grid: tuple[int, int], tile: int, halo: int) -> list[Tile]:
    """Return the tiles of ``grid`` (edge ``tile``), each with ``halo`` neighbours around."""
    rows, cols = grid
    tiles = []
    for r0 in range(0, rows, tile):
        for c0 in range(0, cols, tile):
            r1, c1 = min(r0 + tile, rows), min(c0 + tile, cols)
            hr0, hc0 = max(r0 - halo, 0), max(c0 - halo, 0)
            hr1, hc1 = min(r1 + halo, rows), min(c1 + halo, cols)
            rr, cc = np.meshgrid(np.arange(hr0, hr1), np.arange(hc0, hc1), indexing="ij")
            core = ((rr >= r0) & (rr < r1) & (cc >= c0) & (cc < c1)).ravel()
            actuators = (rr * cols + cc).ravel().astype(np.intp)
            tiles.append(Tile(actuators, (hr1 - hr0, hc1 - hc0), core, actuators[core]))
    return tiles


def compact_grid(
    aligned: AlignedData,
    rows: IndexArray,
    commands: IndexArray,
    gathered: Gathered,
    *,
    temperature: tuple[FloatArray, FloatArray, FloatArray],
    grid: tuple[int, int],
) -> AlignedData:
    """Return the whole grid at ``rows`` of ``aligned`` (a block's alignment) from ``gathered``.

    ``commands`` are the command indices gathered; ``temperature`` the grid's uniform
    times, temperature and rate (align.resample_temperature).
    """
    uniform, temp, rate = temperature
    return replace(
        aligned,
        grid=grid,
        t=aligned.t[rows],
        displacement=gathered.displacement,
        valid=np.isfinite(gathered.displacement),
        command_times=aligned.command_times[commands],
        command=gathered.command,
        command_finite=gathered.command_finite,
        temperature_times=uniform,
        temperature=temp,
        temperature_rate=rate,
        train=aligned.train[rows],
        sample_index=aligned.sample_index[rows],
        command_period_s=aligned.command_period,
    )


def _tile_data(compact: AlignedData, play: dict[float, FloatArray], tile: Tile
               ) -> tuple[AlignedData, dict[float, FloatArray]]:
    act = tile.actuators
    data = replace(
        compact,
        grid=tile.shape,
        displacement=compact.displacement[:, act],
        valid=compact.valid[:, act],
        command=compact.command[:, act],
        command_finite=compact.command_finite[:, act],
        temperature=compact.temperature[:, act],
        temperature_rate=compact.temperature_rate[:, act],
    )
    return data, {r: v[:, act] for r, v in play.items()}


def combine_globals(fits: Sequence[TileFit]) -> tuple[FloatArray, FloatArray]:
    """Return the information-weighted shared values and their covariance over tiles."""
    info = [np.linalg.pinv(f.cov_global) for f in fits]
    total = np.sum(info, axis=0)
    cov = np.linalg.pinv(total)
    glob = cov @ np.sum([i @ f.glob for i, f in zip(info, fits, strict=True)], axis=0)
    return np.asarray(glob, np.float64), np.asarray(cov, np.float64)


def refit_tiles(
    compact: AlignedData,
    play: dict[float, FloatArray],
    state: ModelState,
    start: FloatArray | None,
    *,
    tiles: Sequence[Tile],
    run: TileMap = serial_map,
) -> ModelState:
    """Refit ``state``'s model (its shared values the start) on the grid, tile by tile.

    ``start`` is the grid's local start (A, P) or None (the plain law's own start).
    """
    model = state.model
    A = compact.n_actuators

    def jobs(glob: FloatArray, fixed: bool, local: FloatArray | None) -> list[TileJob]:
        out = []
        for tile in tiles:
            data, tile_play = _tile_data(compact, play, tile)
            out.append(TileJob(
                data, tile_play, tile.core, model.effects, model.operators, state.delay_s,
                state.thresholds, None if local is None else local[tile.actuators], glob, fixed,
            ))
        return out

    def assemble(fits: Sequence[TileFit], field: str) -> FloatArray:
        first = getattr(fits[0], field)
        out = np.empty((A, *first.shape[1:]))
        for tile, fit in zip(tiles, fits, strict=True):
            out[tile.core_actuators] = getattr(fit, field)
        return out

    first = run(fit_tile, jobs(state.fit.glob, False, start))
    glob, cov_g = (first[0].glob, first[0].cov_global)
    final = first
    if len(tiles) > 1 and glob.size:
        glob, cov_g = combine_globals(first)
        final = run(fit_tile, jobs(glob, True, assemble(first, "local")))
    fit = FitResult(
        local=assemble(final, "local"),
        glob=glob,
        cost=assemble(final, "cost"),
        count=assemble(final, "count"),
        cov_local=assemble(first, "cov_local"),
        cov_global=cov_g,
        iterations=max(f.iterations for f in final),
    )
    return ModelState(
        model,
        state.delay_s,
        state.thresholds,
        fit,
        float(assemble(final, "heldout_sse").sum()),
        int(assemble(final, "heldout_count").sum()),
    )
