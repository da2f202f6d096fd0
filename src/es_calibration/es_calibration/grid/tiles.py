"""The grid-wide refit in actuator tiles, each tile an independent task (serial or on Dask).

A tile is a block of at most ``tile`` x ``tile`` actuators; with the coupling (a ``SPATIAL``
effect) it is fitted with a one-actuator halo of its neighbours, whose results are dropped,
so that every kept actuator sees all its neighbours. Each tile is fitted on the samples of
the whole grid's refit (:func:`compact_grid`: the rows search/state.py's budgets choose for the
grid, gathered in one streamed pass into one file per tile, tilestore.py), so a tile's
per-actuator fit uses the same samples whatever the tiling. A task reads its own tile's file:
only its tile is in memory, and on Dask only the file's path travels.

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

from es_calibration.data.align import RESAMPLE_COLUMNS, AlignedData, resample_temperature
from es_calibration.data.recording import COMMAND_FINITE, COMMAND_ROLE, DISPLACEMENT_ROLE
from es_calibration.grid.tilestore import TileStore, play_name
from es_calibration.model.composite import CompositeModel, Evaluation
from es_calibration.model.fit import FitResult, levenberg_marquardt
from es_calibration.search.state import ModelState, Workspace, initial_law
from es_common.arrays import FloatArray, IndexArray

#: Store arrays of the tiles' resampled temperature [degC] and its rate [degC/s].
TEMPERATURE: Final = "temperature"
TEMPERATURE_RATE: Final = "temperature_rate"
#: Default tile edge [actuators].
DEFAULT_TILE: Final = 16

#: Runs a function over jobs, in order: the serial ``map`` or a Dask client's.
TileMap = Callable[[Callable[["TileJob"], "TileFit"], Sequence["TileJob"]], list["TileFit"]]


class DaskSetupError(RuntimeError):
    """The Dask cluster for the tiles could not be started or reached (one-line message)."""


#: What to install for ``--workers``/``--scheduler`` (Dask is an optional dependency: the
#: package.xml declares it under a condition, docs/ros2-install.md "Optional: Dask").
DASK_INSTALL_HINT = (
    "--workers/--scheduler need Dask: pip install 'dask[distributed]' "
    "(ROS: ES_DM_DASK=1 rosdep install --from-paths src --ignore-src)"
)


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
    """One tile's fit: where its data are and where to start (small and picklable, for Dask).

    ``header`` is the grid's time base (:func:`compact_grid`), the tile's arrays are read
    from ``store`` by the task itself; ``gathered_thresholds`` are the play thresholds
    gathered in the store, in order. ``local0`` is None for the plain law's first fit
    (start from the thesis law scaled per actuator); ``fixed`` keeps ``glob0`` fixed.
    """

    header: AlignedData
    store: TileStore
    index: int
    gathered_thresholds: tuple[float, ...]
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
    ws = TileWorkspace(*tile_data(job.header, job.store, job.index, job.gathered_thresholds))
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
    core = job.store.tiles[job.index].core
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


def compact_grid(
    aligned: AlignedData,
    rows: IndexArray,
    commands: IndexArray,
    *,
    temperature_times: FloatArray,
    grid: tuple[int, int],
) -> AlignedData:
    """Return the time base of the grid at ``rows`` of ``aligned`` (a block's alignment).

    ``commands`` are the command indices gathered, ``temperature_times`` the uniform times
    of the resampled temperature (align.resample_temperature). Its per-actuator arrays are
    empty (no actuator): each tile's come from the store (:func:`tile_data`).
    """
    none = np.zeros((0, 0))
    return replace(
        aligned,
        grid=grid,
        t=aligned.t[rows],
        displacement=none.reshape(rows.size, 0),
        valid=np.zeros((rows.size, 0), dtype=bool),
        command_times=aligned.command_times[commands],
        command=none.reshape(commands.size, 0),
        command_finite=np.zeros((commands.size, 0), dtype=bool),
        temperature_times=temperature_times,
        temperature=none.reshape(temperature_times.size, 0),
        temperature_rate=none.reshape(temperature_times.size, 0),
        train=aligned.train[rows],
        sample_index=aligned.sample_index[rows],
        command_period_s=aligned.command_period,
    )


def tile_data(
    header: AlignedData, store: TileStore, index: int, thresholds: Sequence[float]
) -> tuple[AlignedData, dict[float, FloatArray]]:
    """Return tile ``index``'s compact data and play operators, read from ``store``."""
    arrays = store.load(index)
    displacement = np.asarray(arrays[DISPLACEMENT_ROLE], np.float64)
    data = replace(
        header,
        grid=store.tiles[index].shape,
        displacement=displacement,
        valid=np.isfinite(displacement),
        columns=np.asarray(store.tiles[index].actuators, np.intp),
        command=np.asarray(arrays[COMMAND_ROLE], np.float64),
        command_finite=np.asarray(arrays[COMMAND_FINITE], bool),
        temperature=np.asarray(arrays[TEMPERATURE], np.float64),
        temperature_rate=np.asarray(arrays[TEMPERATURE_RATE], np.float64),
    )
    play = {float(r): np.asarray(arrays[play_name(k)], np.float64)
            for k, r in enumerate(thresholds)}
    return data, play


def grid_temperature_mean(times: FloatArray, values: FloatArray) -> tuple[float, int]:
    """Return the grid's mean resampled temperature [degC] and NaN count, block by block.

    ``times`` (Nt,) [s] since the run's start, ``values`` (Nt, A) [degC]: the resampled
    grid is never held whole (align.resample_temperature, per block of actuators).

    Raises:
        CalibrationInputError: an actuator has fewer than 2 finite temperatures.

    """
    total, nan, count = 0.0, 0, 0
    for lo in range(0, values.shape[1], RESAMPLE_COLUMNS):
        _, temp, _, bad = resample_temperature(times, values[:, lo : lo + RESAMPLE_COLUMNS])
        total += float(temp.sum())
        count += temp.size
        nan += bad
    return total / count, nan


def write_temperature(store: TileStore, times: FloatArray, values: FloatArray) -> None:
    """Write each tile's resampled temperature and rate to ``store`` (arrays ``TEMPERATURE``...).

    ``times`` (Nt,) [s] since the run's start, ``values`` (Nt, A) [degC] of the grid.

    Raises:
        CalibrationInputError: an actuator has fewer than 2 finite temperatures.

    """
    for i, tile in enumerate(store.tiles):
        _, temp, rate, _ = resample_temperature(times, values[:, tile.actuators])
        store.put_tile(i, TEMPERATURE, temp)
        store.put_tile(i, TEMPERATURE_RATE, rate)


def combine_globals(fits: Sequence[TileFit]) -> tuple[FloatArray, FloatArray]:
    """Return the information-weighted shared values and their covariance over tiles."""
    info = [np.linalg.pinv(f.cov_global) for f in fits]
    total = np.sum(info, axis=0)
    cov = np.linalg.pinv(total)
    glob = cov @ np.sum([i @ f.glob for i, f in zip(info, fits, strict=True)], axis=0)
    return np.asarray(glob, np.float64), np.asarray(cov, np.float64)


def refit_tiles(
    header: AlignedData,
    store: TileStore,
    gathered_thresholds: Sequence[float],
    state: ModelState,
    start: FloatArray | None,
    *,
    run: TileMap = serial_map,
) -> ModelState:
    """Refit ``state``'s model (its shared values the start) on the grid, tile by tile.

    ``header`` is the grid's time base (:func:`compact_grid`), ``store`` the tiles' data
    with the play operators of ``gathered_thresholds``; ``start`` is the grid's local
    start (A, P) or None (the plain law's own start).
    """
    model = state.model
    tiles = store.tiles
    A = header.grid[0] * header.grid[1]

    def jobs(glob: FloatArray, fixed: bool, local: FloatArray | None) -> list[TileJob]:
        return [
            TileJob(
                header, store, i, tuple(gathered_thresholds), model.effects, model.operators,
                state.delay_s, state.thresholds,
                None if local is None else local[tile.actuators], glob, fixed,
            )
            for i, tile in enumerate(tiles)
        ]

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
