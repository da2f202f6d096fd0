"""Streamed, tiled and Dask calibration (issue 18): same results as the in-memory path."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from es_calibration.data.align import AlignedData, align
from es_calibration.data.bagstream import BagRecording
from es_calibration.data.recording import MemoryRecording, gather, gather_arrays
from es_calibration.errors import RecordingError
from es_calibration.grid.tiles import DASK_INSTALL_HINT, TileJob, compact_grid
from es_calibration.grid.tilestore import TileStore, layout, play_name
from es_calibration.model.composite import LINEAR_LAW, play_operator
from es_calibration.pipeline import calibrate
from es_calibration.search.state import (
    ModelState,
    Workspace,
    base_state,
    choose_stamp_convention,
    fit_state,
    initial_law,
    local_start,
    screen_block,
)
from es_common.arrays import FloatArray, IndexArray
from es_msgs_py.bag import read_bag
from es_msgs_py.bag.stream import iter_bag
from tests.es_calibration import law_bags as lb

from .measured_bags import read_measured_bags

GRID = (10, 10)  # larger than the 8 x 8 screening block: the grid-wide refit runs
EXPANSION_M_PER_DEGC = 0.4e-9
CANDIDATES = ("thermal_expansion",)


def refit_full(aligned: AlignedData, screened: ModelState) -> tuple[ModelState, Workspace]:
    """The in-memory joint refit of a screened model on the whole grid (the reference)."""
    idx = np.arange(aligned.n_actuators, dtype=np.intp)
    ws = Workspace(aligned, idx, aligned.grid)
    train, held = ws.input_pair(screened.delay_s, screened.play_thresholds)
    local0 = local_start(LINEAR_LAW, initial_law(train), screened.model, screened)
    state = fit_state(
        screened.model, train, held, local0, screened.fit.glob,
        delay_s=screened.delay_s, thresholds=screened.thresholds,
    )  # fmt: skip
    return state, ws


def _series(duration: float = 12.0) -> lb.Series:
    run = lb.law_run(duration, seed=3, shape=GRID)
    t, z = run.topics["/dm/displacement"]
    z = z + EXPANSION_M_PER_DEGC * (run.temperature - 40.0)
    return {**run.topics, "/dm/displacement": (t, z)}


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return lb.write(_series(), tmp_path_factory.mktemp("stream") / "bag")


def _run_cli(bag: Path, out: Path, *extra: str) -> dict:
    cmd = [sys.executable, "-m", "es_calibration.calibrate", str(bag), "-o", str(out), "-q",
           "--candidates", ",".join(CANDIDATES), *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=900)
    assert proc.returncode == 0, proc.stderr
    return dict(json.loads((out / "calibration.json").read_text()))


def test_iter_bag_yields_what_read_bag_reads(bag: Path) -> None:
    """Small batches in file order hold every message once, as read_bag decodes them."""
    whole = read_bag(bag)
    stamps: dict[str, list[int]] = {}
    batches = 0
    for batch in iter_bag(bag, batch_bytes=20_000):
        batches += 1
        for topic, raw in batch.items():
            stamps.setdefault(topic, []).extend(raw.stamps)
    assert batches > 1  # one batch per storage chunk at least
    for topic, series in whole.items():
        got = np.sort(np.asarray(stamps[topic])) * 1e-9
        np.testing.assert_allclose(got, series.times, rtol=0, atol=1e-12)


class _Shuffled(MemoryRecording):
    """Batches out of order: the command stream must reorder them before the play loop."""

    def batches(self) -> Iterator[tuple[str, IndexArray, FloatArray]]:
        items = list(super().batches())
        order = np.random.default_rng(0).permutation(len(items))
        return iter([items[i] for i in order])


def test_gather_equals_the_aligned_arrays(tmp_path: Path) -> None:
    series = _series(6.0)
    t, v = series["/dm/command"]
    v = v.copy()
    v[5:40, 0, 1] = np.nan  # held from the last finite value, as align holds it
    v[:3, 2, 2] = np.nan  # before any finite value: 0
    measured = read_measured_bags([lb.write({**series, "/dm/command": (t, v)}, tmp_path / "b")])
    aligned = align(measured)
    rows = np.arange(0, aligned.t.size, 7)
    commands = np.unique(np.maximum(aligned.command_index(rows, 0.02), 0))
    thresholds = [5.0, 20.0]
    tiles = layout(GRID, 4, 1)  # overlapping halos: each tile gets its own columns
    (tmp_path / "store").mkdir()
    store = TileStore.create(tmp_path / "store", tiles,
                             gather_arrays(rows.size, commands.size, len(thresholds)))
    got = gather(_Shuffled(measured), aligned.sample_index[rows], aligned.sample_index,
                 commands, thresholds, store=store)
    for i, tile in enumerate(tiles):
        arrays = store.load(i)
        act = tile.actuators
        np.testing.assert_array_equal(arrays["displacement"], aligned.displacement[rows][:, act])
        np.testing.assert_array_equal(arrays["command"], aligned.command[commands][:, act])
        np.testing.assert_array_equal(arrays["command_finite"],
                                      aligned.command_finite[commands][:, act])
        for k, r in enumerate(thresholds):
            whole = play_operator(aligned.command, r, commands)
            play = np.asarray(arrays[play_name(k)], np.float64)
            np.testing.assert_allclose(play, whole[:, act], rtol=0, atol=1e-12)
    assert got.command_nan == aligned.dropped["command NaN"] == 38
    assert got.usable.sum() == aligned.valid.sum()
    # a task carries the store's path and the time base, not its tile's arrays
    header = compact_grid(aligned, rows, commands, temperature_times=aligned.temperature_times,
                          grid=GRID)
    job = TileJob(header, store, 0, tuple(thresholds), (), 0, 0.0, (), None, np.zeros(0), False)
    assert len(pickle.dumps(job)) < store.path(0).stat().st_size / 4


def test_one_tile_is_the_joint_grid_refit(bag: Path) -> None:
    """The in-memory path (one tile over the grid) is main's joint refit of the grid."""
    measured = read_measured_bags([bag])
    cal = calibrate(measured, (), tile=max(GRID))
    aligned = choose_stamp_convention(align(measured))
    idx, grid = screen_block(aligned.grid)
    joint, _ = refit_full(aligned, base_state(Workspace(aligned, idx, grid)))
    np.testing.assert_allclose(cal.base.fit.local, joint.fit.local, rtol=1e-9)
    assert cal.base.heldout_sse == pytest.approx(joint.heldout_sse, rel=1e-9)


def test_streamed_tiles_equal_the_in_memory_path(bag: Path) -> None:
    """Streamed bag in 3 x 3 tiles (halo-free) vs one in-memory tile: within 1 sigma."""
    memory = calibrate(read_measured_bags([bag]), CANDIDATES, tile=max(GRID))
    streamed = calibrate(BagRecording([bag], batch_bytes=50_000), CANDIDATES, tile=3)
    assert [e.name for e in memory.effects] == [e.name for e in streamed.effects] == list(
        CANDIDATES)
    a, b = memory.final.fit, streamed.final.fit
    sigma_g = np.sqrt(np.diag(a.cov_global))
    assert np.all(np.abs(a.glob - b.glob) <= sigma_g)
    sigma_l = np.sqrt(np.einsum("app->ap", a.cov_local))
    assert np.all(np.abs(a.local - b.local) <= sigma_l)
    expansion = streamed.effects[0].parameters["alpha_m_per_degc"]
    assert expansion == pytest.approx(EXPANSION_M_PER_DEGC, rel=0.05)
    assert streamed.aligned.grid == GRID
    assert streamed.final.heldout_count == memory.final.heldout_count


def test_two_dask_workers_equal_the_serial_run(bag: Path, tmp_path: Path) -> None:
    serial = _run_cli(bag, tmp_path / "serial", "--tile", "4")
    dask = _run_cli(bag, tmp_path / "dask", "--tile", "4", "--workers", "2")
    assert dask["effects"][0]["parameters"] == serial["effects"][0]["parameters"]
    assert dask["law"] == serial["law"]
    assert dask["heldout_rms_after_m"] == serial["heldout_rms_after_m"]


def test_local_workers_keep_the_dynamic_mmap_threshold() -> None:
    """Dask's MALLOC_TRIM_THRESHOLD_ is not in the local workers (dask_tiles.py: it cost 1.7x
    the tile fits' CPU in page faults); its one-thread BLAS limit is. In a child process: the
    nanny writes its pre-spawn environment into the process that starts it."""
    code = (
        "import os\n"
        "from es_calibration.grid.dask_tiles import dask_map\n"
        "names = ('MALLOC_TRIM_THRESHOLD_', 'OPENBLAS_NUM_THREADS')\n"
        "with dask_map(workers=1) as run:\n"
        "    print(run(lambda job: [os.environ.get(n) for n in names], [0]))\n"
    )
    env = {k: v for k, v in os.environ.items()
           if k not in ("MALLOC_TRIM_THRESHOLD_", "OPENBLAS_NUM_THREADS")}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=False, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "[[None, '1']]"


def test_no_dask_import_without_workers(bag: Path, tmp_path: Path) -> None:
    code = (
        "import sys\n"
        "from es_calibration.calibrate import run\n"
        f"status = run([{str(bag)!r}, '-o', {str(tmp_path / 'out')!r}, '-q', "
        f"'--candidates', 'thermal_expansion', '--tile', '4'])\n"
        "assert status == 0, status\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=False, timeout=900)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_workers_without_dask_say_what_to_install_in_one_line(bag: Path, tmp_path: Path) -> None:
    """Dask is optional (package.xml: a conditional dependency): without it, one line that
    names what to install, not the 'internal error' an unguarded import gave."""
    code = (
        "import sys\n"
        "sys.modules['dask'] = None  # as if Dask were not installed\n"
        "from es_calibration.calibrate import run\n"
        f"sys.exit(run([{str(bag)!r}, '-o', {str(tmp_path / 'out')!r}, '-q', '--workers', '1']))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=False, timeout=900)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [f"calibrate: {DASK_INSTALL_HINT} "
                                                "(import of dask halted; None in sys.modules)"]


def test_bad_tile_and_unreachable_scheduler_are_one_line(bag: Path, tmp_path: Path) -> None:
    for extra in (["--tile", "0"], ["--scheduler", "tcp://127.0.0.1:9"]):
        cmd = [sys.executable, "-m", "es_calibration.calibrate", str(bag), "-o",
               str(tmp_path / "o"), "-q", *extra]
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=900)
        assert proc.returncode == 2, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


def test_gather_refuses_a_time_base_without_one_stamp_per_command(tmp_path: Path) -> None:
    # the edge search reads each command's stamp: a time base of another length would
    # decide edges at the wrong instants, so the pass stops with a RecordingError
    measured = read_measured_bags([lb.write(_series(6.0), tmp_path / "b")])
    aligned = align(measured)
    rows = np.arange(0, aligned.t.size, 7)
    commands = np.unique(np.maximum(aligned.command_index(rows, 0.0), 0))
    tiles = layout(GRID, 4, 0)
    (tmp_path / "store").mkdir()
    store = TileStore.create(tmp_path / "store", tiles, gather_arrays(rows.size, commands.size, 0))
    with pytest.raises(RecordingError, match="command stamps"):
        gather(MemoryRecording(measured), aligned.sample_index[rows], aligned.sample_index,
               commands, [], store=store, command_times=aligned.command_times[:-5])
