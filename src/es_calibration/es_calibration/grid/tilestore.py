"""The grid's gathered samples on disk, one file per actuator tile, so no process holds the grid.

The grid-wide refit (tiles.py) fits actuator tiles on a bounded number of rows of the whole
grid. Those rows are gathered in one streamed pass over the recording (recording.py), and
each batch's rows go straight to the files of the tiles (:meth:`TileStore.put`): the pass
holds one batch, never the grid's rows. A tile's fit then reads only its own file
(:meth:`TileStore.load`), in this process or in a Dask worker (the store is a directory
path and the tiling: small to send).

Each tile's file holds, one after the other, its arrays (name -> rows x the tile's
actuators, row-major): ``displacement``, ``command``, ``command_finite``, ``temperature``,
``temperature_rate`` and one ``play<k>`` per play threshold. The directory is the caller's
(a temporary directory; with a remote Dask scheduler it must be one the workers can read).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from es_calibration.errors import RecordingError
from es_common.arrays import IndexArray


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


def play_name(k: int) -> str:
    """Return the store's array name of the ``k``-th play threshold's operator."""
    return f"play{k}"


@dataclass(frozen=True)
class TileStore:
    """Per-tile files under ``directory`` (see the module docstring); picklable.

    Attributes:
        directory: where the files are.
        tiles: the tiling.
        arrays: name -> (rows, dtype string) of each array.

    """

    directory: Path
    tiles: tuple[Tile, ...]
    arrays: tuple[tuple[str, int, str], ...]

    @classmethod
    def create(
        cls, directory: Path, tiles: list[Tile], arrays: Mapping[str, tuple[int, str]]
    ) -> TileStore:
        """Make the (empty, zero-filled) files of every tile under ``directory``."""
        store = cls(directory, tuple(tiles), tuple((n, r, d) for n, (r, d) in arrays.items()))
        for i, tile in enumerate(tiles):
            with store.path(i).open("wb") as handle:
                handle.truncate(store._offset(tile, None))
        return store

    def path(self, index: int) -> Path:
        """Return the file of tile ``index``."""
        return self.directory / f"tile-{index:06d}.bin"

    def _offset(self, tile: Tile, name: str | None, row: int = 0) -> int:
        """Return the byte offset of ``name``'s ``row`` in ``tile``'s file (None: its size)."""
        width = tile.actuators.size
        offset = 0
        for n, rows, dtype in self.arrays:
            item = np.dtype(dtype).itemsize
            if n == name:
                return offset + row * width * item
            offset += rows * width * item
        if name is not None:
            raise KeyError(name)
        return offset

    def put(self, name: str, row: int, block: npt.NDArray[np.generic]) -> None:
        """Write grid rows ``block`` (k, A) as rows ``row .. row + k`` of array ``name``.

        Raises:
            RecordingError: the block does not fit in the array.

        """
        rows, dtype = next((r, d) for n, r, d in self.arrays if n == name)
        if row < 0 or row + block.shape[0] > rows:
            raise RecordingError(f"rows {row}..{row + block.shape[0]} outside {name} ({rows})")
        for i, tile in enumerate(self.tiles):
            part = np.ascontiguousarray(block[:, tile.actuators], dtype=dtype)
            fd = os.open(self.path(i), os.O_WRONLY)
            try:
                os.pwrite(fd, part.tobytes(), self._offset(tile, name, row))
            finally:
                os.close(fd)

    def put_tile(self, index: int, name: str, values: npt.NDArray[np.generic]) -> None:
        """Write the whole array ``name`` of tile ``index``: ``values`` (rows, its actuators)."""
        tile = self.tiles[index]
        rows, dtype = next((r, d) for n, r, d in self.arrays if n == name)
        if values.shape != (rows, tile.actuators.size):
            raise RecordingError(f"{name} of tile {index} is {values.shape}, not "
                                 f"{(rows, tile.actuators.size)}")
        with self.path(index).open("r+b") as handle:
            handle.seek(self._offset(tile, name))
            handle.write(np.ascontiguousarray(values, dtype=dtype).tobytes())

    def load(self, index: int) -> dict[str, npt.NDArray[np.generic]]:
        """Return tile ``index``'s arrays, name -> (rows, the tile's actuators)."""
        tile = self.tiles[index]
        width = tile.actuators.size
        out: dict[str, npt.NDArray[np.generic]] = {}
        with self.path(index).open("rb") as handle:
            for name, rows, dtype in self.arrays:
                values = np.fromfile(handle, dtype=dtype, count=rows * width)
                out[name] = values.reshape(rows, width)
        return out
