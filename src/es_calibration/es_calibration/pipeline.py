"""The whole calibration: align, fit, analyse the residual, add effects, refit on the grid.

``calibrate(measured)`` returns a :class:`Calibration` holding every step's outcome; the
report, ``calibration.json`` and the parameters YAML are written from it (report.py,
schema.py).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Final

import numpy as np

from es_calibration.data.align import (
    LATE_BURST_DROPS,
    MIN_SAMPLES,
    AlignedData,
    CalibrationInputError,
    MeasuredData,
    align,
    resample_temperature,
    temperature_stamps,
)
from es_calibration.data.edges import EdgeExclusion, EdgeMask, account
from es_calibration.data.recording import MemoryRecording, Recording, gather, gather_arrays
from es_calibration.data.searchspan import SEARCH_BUDGET, search_span, search_windows
from es_calibration.data.timing import (
    clock_rate,
    clock_rate_finding,
    corrected_times,
    receive_jitter,
    stamp_findings,
)
from es_calibration.discovery import Discovery, discover, refit_with_terms
from es_calibration.discovery.standins import drop_stand_ins
from es_calibration.grid.tiles import (
    DEFAULT_TILE,
    TEMPERATURE,
    TEMPERATURE_RATE,
    TileMap,
    compact_grid,
    grid_temperature_mean,
    refit_tiles,
    serial_map,
    write_temperature,
)
from es_calibration.grid.tilestore import TileStore, layout
from es_calibration.health.actuators import check_actuators
from es_calibration.health.findings import Finding
from es_calibration.health.sensors import check_sensors
from es_calibration.model.composite import CANDIDATES
from es_calibration.search import unexplained
from es_calibration.search.blockdelay import block_delays
from es_calibration.search.halves import check_halves
from es_calibration.search.local import per_actuator_round
from es_calibration.search.residual import ResidualStructure, analyse
from es_calibration.search.selection import (
    RoundRecord,
    Step,
    preferred_final,
    search_effects,
    subset_state,
)
from es_calibration.search.state import (
    MIN_RELATIVE_GAIN,
    ModelState,
    Workspace,
    base_state,
    choose_stamp_convention,
    fitted_effect,
    heldout_residual,
    refit_state,
    screen_block,
)
from es_calibration.search.unexplained import NOISE_RATIO_LIMIT
from es_calibration.verdict import Verdict, judge, law_problems
from es_common.arrays import FloatArray, IndexArray
from es_physics.effects import get
from es_physics.params import ActuatorParams

#: Actuators whose full-rate held-out residual is analysed (spectra, correlations).
ANALYSIS_ACTUATORS: Final = 16
#: Held-out rows analysed at full rate, at most.
ANALYSIS_ROWS: Final = 50_000


@dataclass
class AcceptedEffect:
    """An effect the search added, with its full-grid held-out RMS before and after.

    ``parameters`` and ``uncertainties`` are those of the final model (all accepted effects
    fitted together); a parameter fitted per actuator is given there as the grid's median,
    and in ``per_actuator`` / ``per_actuator_uncertainties`` as row-major lists of R*C
    values. ``share`` is its part of the mean-square error that all accepted effects
    removed, (before^2 - after^2) / (base^2 - final^2): the shares sum to 1.
    """

    name: str
    parameters: dict[str, float]
    uncertainties: dict[str, float]
    rms_before_m: float
    rms_after_m: float
    share: float = 0.0
    per_actuator: dict[str, list[float]] = field(default_factory=dict)
    per_actuator_uncertainties: dict[str, list[float]] = field(default_factory=dict)
    #: False: found but it did not hold on the record's halves (written switched off).
    enabled: bool = True


@dataclass
class Calibration:
    """Everything the calibration found (see schema.py for the JSON form).

    ``aligned`` describes the run (grid, time base, drops, gaps); its per-actuator arrays
    hold the screening block's actuators only (the whole grid is never held at full rate).
    """

    aligned: AlignedData
    base: ModelState
    final: ModelState
    effects: list[AcceptedEffect]
    rounds: list[RoundRecord]
    before: ResidualStructure
    after: ResidualStructure
    analysis_before: tuple[FloatArray, FloatArray]  # (t, residual (A, n)) for the figures
    analysis_after: tuple[FloatArray, FloatArray]
    analysis_inputs: dict[str, FloatArray]
    unexplained: list[str]
    timings_s: dict[str, float] = field(default_factory=dict)
    #: What of the record the effect search saw ("" : all of it; else the windows, in words).
    search_span: str = ""
    #: The discovery step's outcome (terms beyond the registry), None when it did not run.
    discovery: Discovery | None = None
    #: Faults of the recording and of the actuators, found and named (health/).
    findings: list[Finding] = field(default_factory=list)
    #: The displacement clock's rate against the command's [ppm] (None: not estimated).
    clock_rate_ppm: float | None = None
    #: Share of the screening block's (sample, actuator) pairs kept for the fit.
    kept_fraction: float = 1.0
    #: What every actuator's own command edges take out of the grid beyond the screening
    #: block (None: the grid is the block, its edges are ``aligned.command_edges``).
    grid_edges: EdgeExclusion | None = None
    #: Share of the whole grid's (sample, actuator) pairs kept, at least (None: as above).
    grid_kept_fraction: float | None = None
    verdict: Verdict = field(default_factory=lambda: Verdict("trusted"))

    @property
    def noise_floor_m(self) -> float:
        """Return the measurement noise estimate from the final residual [m]."""
        return self.after.noise_floor


class _Analysis:
    """Full-rate held-out rows of a few actuators, for residual structure."""

    def __init__(self, aligned: AlignedData) -> None:
        idx, grid = screen_block(aligned.grid)
        n = min(ANALYSIS_ACTUATORS, idx.size)
        self.ws = Workspace(aligned, idx, grid)  # coupling needs the whole screening block
        self.keep = np.arange(n)
        rows = np.flatnonzero(~aligned.train)[:ANALYSIS_ROWS]
        self.ws.score_rows = rows
        self.rows = rows
        self.contiguous = aligned.linked(rows)

    def residual(self, state: ModelState) -> FloatArray:
        _, held = self.ws.input_pair(state.delay_s, state.play_thresholds)
        return heldout_residual(state, held)[self.keep]

    def regressors(self) -> dict[str, tuple[str, FloatArray]]:
        a = self.ws.aligned
        act = self.ws.actuators[self.keep]
        rows = self.rows
        V = a.command[np.ix_(np.maximum(a.command_index(rows), 0), act)].T
        dV = np.gradient(V, a.t[rows], axis=1)
        # no derivative across a break between runs (a gap or a block edge): NaN there
        broken = np.zeros(rows.size, dtype=bool)
        broken[:-1] |= ~self.contiguous
        broken[1:] |= ~self.contiguous
        dV[:, broken] = np.nan
        return {
            "V": ("V", V),
            "dV/dt": ("V/s", dV),
            "T": ("degC", a.temperature_at(rows, act)),
            "dT/dt": ("degC/s", a.temperature_rate_at(rows, act)),
            "time": ("s", np.broadcast_to(a.t[rows], V.shape)),
        }

    def analyse(self, state: ModelState) -> tuple[ResidualStructure, FloatArray]:
        resid = self.residual(state)
        rate = self.ws.aligned.sample_rate
        inputs = self.regressors()
        voltage = inputs["V"][1]
        structure = analyse(resid, self.contiguous, rate, inputs)
        structure.drive_tones_hz = unexplained.drive_tones(voltage, self.contiguous, rate)
        z = self.ws.aligned.displacement[np.ix_(self.rows, self.ws.actuators[self.keep])].T
        structure.drive_gain_m_per_v = unexplained.drive_gain(voltage, z)
        return structure, resid


class _RepairedTemperature:
    """A :class:`Recording` whose temperature readings were repaired (health/sensors.py)."""

    def __init__(self, recording: Recording, temperature: FloatArray) -> None:
        self._recording = recording
        self._temperature = temperature

    @property
    def grid(self) -> tuple[int, int]:
        """Return the actuator grid (rows, cols)."""
        return self._recording.grid

    def block(self, columns: IndexArray, shape: tuple[int, int]) -> MeasuredData:
        """Return the block with its repaired temperature."""
        data = self._recording.block(columns, shape)
        return replace(data, temperature=self._temperature[:, columns].reshape(-1, *shape))

    def temperature(self) -> tuple[FloatArray, FloatArray]:
        """Return the temperature stamps and the repaired values (Nt, A)."""
        return self._recording.temperature()[0], self._temperature

    def batches(self) -> Iterator[tuple[str, IndexArray, FloatArray]]:
        """Yield the recording's command and displacement batches."""
        return self._recording.batches()


def _checked_sensors(recording: Recording) -> tuple[Recording, list[Finding], float]:
    """Check the temperature sensors; return the recording (repaired), findings, first stamp."""
    times, values = recording.temperature()
    if times.size == 0 or values.ndim != 2:
        return recording, [], 0.0
    start = float(times[0])
    health = check_sensors(times, values, recording.grid, start)
    if not health.findings:
        return recording, [], start
    return _RepairedTemperature(recording, health.temperature), health.findings, start


def fitted_law(state: ModelState, grid: tuple[int, int]) -> ActuatorParams:
    """Return the law of ``state``'s fit as per-actuator maps (R, C)."""
    local = state.fit.local
    model = state.model
    values = {
        n: local[:, i].reshape(grid)
        for i, n in enumerate(model.local_names)
        if n not in model.per_actuator  # effects' parameters, not the law's
    }
    return replace(ActuatorParams().as_arrays(grid), **values)


def _unexplained(after: ResidualStructure, final_rms: float) -> list[str]:
    """Describe the structure the final model leaves, in words."""
    return unexplained.describe(after, final_rms, NOISE_RATIO_LIMIT)


@dataclass(frozen=True)
class _GridRefit:
    """The grid-wide refit: the refitted models, NaN counts, the actuators' own edges.

    Attributes:
        states: each screened model refitted on the whole grid.
        dropped: NaN displacements and commands of the whole grid (``dropped`` counts).
        edges: every actuator's own command edges (None: not looked for).
        usable: finite displacement (sample, actuator) pairs among the kept samples.

    """

    states: list[ModelState]
    dropped: dict[str, int]
    edges: EdgeMask | None
    usable: int


def _grid_refit(
    recording: Recording,
    aligned: AlignedData,
    states: list[ModelState],
    *,
    temperature: tuple[FloatArray, FloatArray],
    tile: int,
    run: TileMap,
    own_edges: bool,
) -> _GridRefit:
    """Refit each model of ``states`` on the whole grid in tiles.

    ``aligned`` is the screening block's alignment (the time base of the whole run; its
    edge mask names grid indices), ``temperature`` the grid's stamps since the run's start
    (Nt,) [s] and values (Nt, A) [degC]. One streamed pass writes the grid at the refit's
    samples to one file per tile (recording.gather, tilestore.py), each tile's resampled
    temperature with it; with ``own_edges`` it also finds each actuator's own command edges,
    which then take the actuator's samples (at ``aligned``'s window) instead of the block's.

    Raises:
        CalibrationInputError: an actuator has fewer than ``MIN_SAMPLES`` usable samples.

    """
    grid = recording.grid
    A = grid[0] * grid[1]
    sizing = Workspace(aligned, np.arange(A, dtype=np.intp), grid)  # the grid's row budgets
    rows = np.union1d(sizing.fit_rows, sizing.score_rows)
    needed = []
    for state in states:
        whole, _ = sizing.split_delay(state.delay_s)
        for shift in {0.0, state.delay_s, whole, whole + aligned.command_period}:
            needed.append(aligned.command_index(rows, shift))
    commands = np.unique(np.concatenate(needed))
    commands = commands[commands >= 0]
    thresholds = sorted({r for s in states if s.model.play for r in s.thresholds})
    halo = 1 if any(s.model.spatial for s in states) else 0
    times, values = temperature
    tiles = layout(grid, tile, halo)
    with tempfile.TemporaryDirectory(prefix="es_calibrate_tiles_") as directory:
        uniform = resample_temperature(times, values[:, :1])[0]
        arrays = gather_arrays(rows.size, commands.size, len(thresholds))
        arrays.update({TEMPERATURE: (uniform.size, "float64"),
                       TEMPERATURE_RATE: (uniform.size, "float64")})
        store = TileStore.create(Path(directory), tiles, arrays)
        write_temperature(store, times, values)
        gathered = gather(recording, aligned.sample_index[rows], aligned.sample_index, commands,
                          thresholds, store=store,
                          command_times=aligned.command_times if own_edges else None)
        if gathered.usable.min() < MIN_SAMPLES:
            worst = int(np.argmin(gathered.usable))
            raise CalibrationInputError(
                f"too short to fit: actuator {worst} has {int(gathered.usable[worst])} usable "
                f"samples (need {MIN_SAMPLES})"
            )
        grid_mask = None
        if gathered.edges is not None:
            window = aligned.edge_mask
            grid_mask = replace(gathered.edges, before_s=window.before_s,
                                after_s=window.after_s, delay_s=window.delay_s)
            aligned = replace(aligned, edge_mask=grid_mask)
        header = compact_grid(aligned, rows, commands, temperature_times=uniform, grid=grid)
        out: list[ModelState] = []
        for state in states:
            start = out[-1].fit.local if out else None
            out.append(refit_tiles(header, store, thresholds, state, start, run=run))
    counts = {
        "displacement NaN": gathered.displacement_nan,
        "command NaN": gathered.command_nan,
    }
    return _GridRefit(out, counts, grid_mask, int(gathered.usable.sum()))


def _grid_temperature(recording: Recording, start: float) -> tuple[FloatArray, FloatArray]:
    """Return the grid's temperature stamps since ``start`` (Nt,) [s] and values (Nt, A)."""
    times, values = recording.temperature()
    return temperature_stamps(times) - start, values


def _screened(
    aligned: AlignedData, block_grid: tuple[int, int], candidates: tuple[str, ...]
) -> tuple[Workspace, ModelState, ModelState, list[Step], list[RoundRecord]]:
    """Search the effects on the screening block: (workspace, base, final, steps, rounds)."""
    screen = Workspace(aligned, np.arange(aligned.n_actuators, dtype=np.intp), block_grid)
    base = base_state(screen)
    final, added, rounds = search_effects(screen, base, candidates)
    return screen, base, final, added, rounds


def _search(
    aligned: AlignedData, block_grid: tuple[int, int], candidates: tuple[str, ...]
) -> tuple[AlignedData, Workspace, ModelState, ModelState, list[Step], list[RoundRecord]]:
    """Search the effects; with lock-step stamps, check the stamp convention once more.

    The convention (is a command in effect at its own stamp?) was chosen with the plain law;
    an effect the law lacks can make that choice wrong, which leaves a one-period timing
    error. A final model without a command shift is refitted with the other convention; when
    that cuts its held-out RMS by ``MIN_RELATIVE_GAIN``, the search runs again with it. A
    final shift within a period of none may be that timing error taken up by a delay: the
    search runs again with the other convention. The preferred final is kept
    (:func:`~es_calibration.search.selection.preferred_final`).
    """
    screen, base, final, added, rounds = _screened(aligned, block_grid, candidates)
    first = (aligned, screen, base, final, added, rounds)
    if not aligned.has_same_stamps or not final.model.effects:
        return first
    other = replace(aligned, include_same_stamp=not aligned.include_same_stamp)
    if final.model.shift is None:
        refit = subset_state(
            Workspace(other, screen.actuators, screen.grid), final, final.model.effects
        )
        if refit.heldout_rms >= (1.0 - MIN_RELATIVE_GAIN) * final.heldout_rms:
            return first
    elif abs(final.delay_s) > aligned.command_period * (1.0 + 1e-6):
        return first
    second = _screened(other, block_grid, candidates)
    return (other, *second) if preferred_final(second[2], final) else first


def _align_block(
    recording: Recording, clock_fraction: float = 0.0
) -> tuple[AlignedData, MeasuredData]:
    """Return the screening block's alignment (stamp convention chosen) and its data.

    ``clock_fraction`` corrects the displacement stamps of a clock that fast (timing.py).
    """
    grid = recording.grid
    idx, block_grid = screen_block(grid)
    data = recording.block(idx, block_grid)
    if clock_fraction:
        origin = float(data.displacement_times[0])
        data = replace(data, displacement_times=corrected_times(
            data.displacement_times, clock_fraction, origin))
    # a delay within the stamps' jitter may be their own lateness (identifiable.py)
    block = replace(align(data), stamp_jitter_s=receive_jitter(data.displacement_times))
    if block_grid != grid:  # the block's model inputs use the whole grid's mean temperature
        grid_temperature = _grid_temperature(recording, block.start_time)
        mean, temp_nan = grid_temperature_mean(*grid_temperature)
        block = replace(block, grid_mean_temperature=mean)
        block.dropped["temperature NaN"] = temp_nan
    return choose_stamp_convention(block), data


def _timing_health(recording: Recording) -> tuple[AlignedData, list[Finding], float]:
    """Align the screening block with its timing checked (data/timing.py).

    Returns the alignment (on the corrected displacement time base when the two loggers'
    clocks differ), the timing findings and the clock-rate difference [ppm]. After a
    correction the delays are measured again: a rate still left is corrected on top.
    """
    aligned, data = _align_block(recording)
    origin = aligned.start_time
    findings = [
        *stamp_findings("command logger", data.command_times, origin,
                        burst_action="reported; stamps used as recorded"),
        *stamp_findings("displacement logger", data.displacement_times, origin,
                        burst_action=f"samples left out ({LATE_BURST_DROPS})"),
    ]
    duration = float(aligned.t[-1])
    fraction = 0.0
    rate = clock_rate(*block_delays(aligned), aligned.command_period, duration)
    first = rate
    for _ in range(2):  # the correction, and what is left after it
        if not rate.significant:
            break
        fraction = (1.0 + fraction) * (1.0 + rate.fraction) - 1.0
        aligned, _ = _align_block(recording, fraction)
        rate = clock_rate(*block_delays(aligned), aligned.command_period, duration)
    if fraction:
        total = replace(first, ppm=fraction * 1e6, drift_s=fraction * duration)
        findings.append(clock_rate_finding(total, duration))
        return aligned, findings, fraction * 1e6
    return aligned, findings, first.ppm


def _refitted(ws: Workspace, state: ModelState) -> ModelState:
    """Return ``state``'s model (per-actuator parameters kept) refitted on ``ws``, from it."""
    train, held = ws.input_pair(state.delay_s, state.play_thresholds)
    return refit_state(state, train, held)


def _with_delay(aligned: AlignedData, delay_s: float) -> AlignedData:
    """Return ``aligned`` whose edges take only what a known delay ``delay_s`` needs."""
    mask = aligned.edge_mask.with_delay(aligned.command_period, delay_s)
    edges = account(mask.shifted(-aligned.start_time), aligned.t + aligned.start_time,
                    aligned.displacement.shape[1])
    return replace(aligned, edge_mask=mask, command_edges=edges)


def calibrate(
    measured: MeasuredData | Recording,
    candidates: tuple[str, ...] = CANDIDATES,
    *,
    tile: int = DEFAULT_TILE,
    run: TileMap = serial_map,
    search_budget: int = SEARCH_BUDGET,
) -> Calibration:
    """Run the whole calibration; raise CalibrationInputError on bad data.

    Args:
        measured: the run, in memory or a streamed recording
            (:class:`.data.bagstream.BagRecording`).
        candidates: effects to test.
        tile: edge of the actuator tiles of the grid-wide refit [actuators]; a tile as
            large as the grid is the in-memory joint fit.
        run: how tiles run (:func:`~es_calibration.grid.tiles.serial_map`, or a Dask
            client's map, see dask_tiles.py).
        search_budget: sample-actuator values the effect search sees at most; a longer
            record is searched on windows spread over it (searchspan.py), and then refitted
            on the grid from the whole record even when the grid is the screening block.

    Raises:
        CalibrationInputError: the data cannot be calibrated (too short, wrong layout...).
        SearchBudgetError: ``search_budget`` is not positive.

    """
    recording = MemoryRecording(measured) if isinstance(measured, MeasuredData) else measured
    timings: dict[str, float] = {}
    clock = time.perf_counter()
    recording, sensor_findings, temperature_start = _checked_sensors(recording)
    timings["sensor health"] = time.perf_counter() - clock
    clock = time.perf_counter()
    grid = recording.grid
    idx, block_grid = screen_block(grid)
    full_grid = block_grid == grid
    aligned, findings, ppm = _timing_health(recording)
    if not full_grid:
        grid_temperature = _grid_temperature(recording, aligned.start_time)
    searched = search_span(aligned, search_budget)
    windowed = searched is not aligned
    span_note = (
        f"{len(search_windows(aligned, search_budget))} windows, "
        f"{searched.t.size / aligned.sample_rate:.1f} s of the record's "
        f"{aligned.t.size / aligned.sample_rate:.1f} s (search budget {search_budget} "
        "sample-actuator values); the grid refit and its scores use the whole record"
        if windowed
        else ""
    )
    timings["align"] = time.perf_counter() - clock

    clock = time.perf_counter()
    searched, screen, base_screen, final_screen, added, rounds = _search(
        searched, block_grid, candidates
    )
    if not windowed:
        aligned = searched
    elif searched.include_same_stamp != aligned.include_same_stamp:
        aligned = replace(aligned, include_same_stamp=searched.include_same_stamp)
    record, refined = per_actuator_round(screen, final_screen)
    halves, unconfirmed = check_halves(screen, refined)
    del screen, searched  # their caches (filtered drives, play operators) are done with
    if record is not None:
        rounds.append(record)
    if halves is not None:
        rounds.append(halves)
    if refined is not final_screen:
        name, before_state, _ = added[-1]
        added[-1] = (name, before_state, refined)
        final_screen = refined
    timings["effect search"] = time.perf_counter() - clock

    clock = time.perf_counter()
    # the delay is known: an edge takes only the samples that delay needs (edges.py)
    aligned = _with_delay(aligned, final_screen.delay_s)
    kept = aligned.kept_fraction()
    analysis = _Analysis(aligned)
    before, resid_before = analysis.analyse(base_screen)
    after, resid_after = analysis.analyse(final_screen)
    timings["residual analysis"] = time.perf_counter() - clock
    # terms no registry effect describes, searched in the block's held-out residual
    discovery = discover(aligned, block_grid, final_screen, after.noise_floor,
                         placement=(idx, grid))
    if discovery.added and full_grid and not windowed:  # the terms will be added: stand-ins?
        clock = time.perf_counter()
        narrow = Workspace(aligned, np.arange(aligned.n_actuators, dtype=np.intp), block_grid)
        added, discovery, stand_ins = drop_stand_ins(
            narrow, base_screen, added, discovery,
            lambda state: discover(aligned, block_grid, state, after.noise_floor,
                                   placement=(idx, grid)))
        if stand_ins is not None:
            rounds.append(stand_ins)
            final_screen = added[-1][2] if added else base_screen
            unconfirmed &= {name for name, _, _ in added}
            if stand_ins.removed:
                after, resid_after = analysis.analyse(final_screen)
        discovery.seconds += time.perf_counter() - clock

    clock = time.perf_counter()
    grid_edges: EdgeExclusion | None = None
    grid_kept: float | None = None
    screened = [base_screen] + [after_state for _, _, after_state in added]
    if full_grid and not windowed:
        # refitted on the pairs the known delay keeps
        narrow = Workspace(aligned, np.arange(aligned.n_actuators, dtype=np.intp), block_grid)
        prefix_states = [_refitted(narrow, s) for s in screened]
    else:
        if full_grid:
            grid_temperature = _grid_temperature(recording, aligned.start_time)
        # the block's edges named by grid index (for their window; beyond the block the
        # refit's pass over the recording finds every actuator's own, _grid_refit)
        on_grid = aligned if full_grid else replace(
            aligned, edge_mask=aligned.edge_mask.renumbered(idx))
        refit = _grid_refit(
            recording, on_grid, screened, temperature=grid_temperature, tile=tile, run=run,
            own_edges=not full_grid,
        )
        prefix_states = refit.states
        aligned = replace(aligned, dropped={**aligned.dropped, **refit.dropped})
        if refit.edges is not None:
            # at least: a pair with a NaN and an edge counts twice as lost
            grid_edges = account(refit.edges, aligned.t, grid[0] * grid[1])
            grid_kept = (refit.usable - grid_edges.excluded_pairs) / max(
                max(aligned.recorded_samples, aligned.t.size) * grid[0] * grid[1], 1)
    timings["grid refit"] = time.perf_counter() - clock
    clock = time.perf_counter()
    base_full = prefix_states[0]
    final = prefix_states[-1]
    if discovery.added:
        clock = time.perf_counter()
        if full_grid and not windowed:  # the model's values of the joint fit with the terms
            final = refit_with_terms(
                Workspace(aligned, np.arange(aligned.n_actuators, dtype=np.intp), block_grid),
                final, discovery, placement=(idx, grid))
            discovery.seconds += time.perf_counter() - clock
        else:
            discovery.added = False
            discovery.note = (
                "the terms were found on the screening block, and the grid beyond it (or the "
                "record beyond the search's windows) was not refitted with them: reported, "
                "not added")
    timings["discovery"] = discovery.seconds
    # re-express the uncertainties with the residual's autocorrelation
    if after.tau_int > 1.0:
        final.fit = replace(
            final.fit,
            cov_local=final.fit.cov_local * after.tau_int,
            cov_global=final.fit.cov_global * after.tau_int,
        )
    # the run's description: the whole grid on the block's time base
    aligned = replace(aligned, grid=grid)

    effects = []
    for (name, _, _), prev, state in zip(added, prefix_states[:-1], prefix_states[1:], strict=True):
        effect = get(name)
        # parameters from the final model: every effect refitted with all the others
        fitted = fitted_effect(final, effect, aligned)
        local = [p for p in effect.local_options if p in fitted.local]
        effects.append(
            AcceptedEffect(
                name,
                effect.reported(fitted),
                effect.uncertainties(fitted),
                prev.heldout_rms,
                state.heldout_rms,
                per_actuator={p: fitted.local[p].tolist() for p in local},
                per_actuator_uncertainties={p: fitted.local_sigma[p].tolist() for p in local},
                enabled=name not in unconfirmed,
            )
        )
    removed = base_full.heldout_rms**2 - final.heldout_rms**2
    for e in effects:
        cut = e.rms_before_m**2 - e.rms_after_m**2
        e.share = float(cut / removed) if removed > 0 else 0.0
    inputs = {k: v for k, (_, v) in analysis.regressors().items()}
    shift = temperature_start - aligned.start_time  # spans from the displacement's start
    findings += [
        replace(f, start_s=f.start_s + shift, end_s=f.end_s + shift) for f in sensor_findings
    ]
    law = fitted_law(final, grid)
    findings += check_actuators(law, aligned.mean_temperature, float(aligned.t[-1]))
    described = _unexplained(after, final.heldout_rms) + (
        [discovery.note] if discovery.searched and discovery.note else []
    )
    finite = aligned.temperature[np.isfinite(aligned.temperature)]
    recorded = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    verdict = judge(
        law=law_problems(law, recorded),
        kept_fraction=kept if grid_kept is None else min(kept, grid_kept),
        heldout_rms_m=final.heldout_rms,
        noise_floor_m=after.noise_floor,
        unexplained=described,
        findings=findings,
        unconfirmed=sorted(unconfirmed),
    )
    return Calibration(
        aligned=aligned,
        base=base_full,
        final=final,
        effects=effects,
        rounds=rounds,
        before=before,
        after=after,
        analysis_before=(aligned.t[analysis.rows], resid_before),
        analysis_after=(aligned.t[analysis.rows], resid_after),
        analysis_inputs=inputs,
        unexplained=described,
        timings_s=timings,
        search_span=span_note,
        discovery=discovery,
        findings=findings,
        clock_rate_ppm=ppm,
        kept_fraction=kept,
        grid_edges=grid_edges,
        grid_kept_fraction=grid_kept,
        verdict=verdict,
    )


__all__ = ["AcceptedEffect", "Calibration", "calibrate", "fitted_law"]
