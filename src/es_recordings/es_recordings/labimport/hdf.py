"""HDF5 recordings (``.h5``/``.hdf5``) and MATLAB v7.3 files, read in slices with h5py.

Plain HDF5: datasets by path (``group/dataset``), shapes as stored. MATLAB v7.3: MATLAB
writes arrays column-major, so h5py sees their dimensions reversed; they are shown in
MATLAB's order with size-1 dimensions dropped (as scipy.io shows v5 files), struct fields
as ``struct.field``; MATLAB's internal groups (``#refs#``, ``#subsystem#``) are skipped.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from es_recordings.labimport.errors import SourceError
from es_recordings.labimport.recording import FloatArray, Variable, first_line, numeric_dtype

_MATLAB_NON_NUMERIC = (b"char", b"cell", b"function_handle")


@dataclass(frozen=True)
class _Dataset:
    path: str
    #: The stored axes that are shown, in the order shown.
    axes: tuple[int, ...]


class HdfSource:
    """An HDF5 file (``matlab``: a MATLAB v7.3 MAT file) opened for import."""

    def __init__(self, path: Path, matlab: bool) -> None:
        """Open ``path`` and list its datasets.

        Raises:
            SourceError: the file is not HDF5, or damaged or truncated.

        """
        self.path = path
        self._matlab = matlab
        kind = "MATLAB v7.3 file" if matlab else "HDF5 file"
        self._kind = kind
        try:
            self._file = h5py.File(path, "r")
        except OSError as err:
            raise SourceError(f"{path}: corrupt or truncated {kind} ({first_line(err)})") from None
        self._datasets: dict[str, _Dataset] = {}
        self._variables: dict[str, Variable] = {}
        try:
            self._file.visititems(self._visit)
        except (OSError, RuntimeError, KeyError) as err:
            self._file.close()
            raise SourceError(f"{path}: corrupt or truncated {kind} ({first_line(err)})") from None

    def _visit(self, name: str, obj: object) -> None:
        if not isinstance(obj, h5py.Dataset):
            return
        if self._matlab and name.startswith("#"):
            return
        shape = tuple(int(n) for n in obj.shape)
        numeric = numeric_dtype(obj.dtype)
        if self._matlab:
            numeric = numeric and obj.attrs.get("MATLAB_class", b"double") not in (
                _MATLAB_NON_NUMERIC
            )
            axes = tuple(ax for ax in reversed(range(len(shape))) if shape[ax] != 1)
            name = name.replace("/", ".")
        else:
            axes = tuple(range(len(shape)))
        self._datasets[name] = _Dataset(obj.name or name, axes)
        self._variables[name] = Variable(
            name, tuple(shape[ax] for ax in axes), str(obj.dtype), numeric
        )

    def variables(self) -> Mapping[str, Variable]:
        """Every dataset by name."""
        return self._variables

    def read(self, names: Sequence[str], axes: Sequence[int], start: int, stop: int
             ) -> list[FloatArray]:
        """Return samples ``start:stop`` of each dataset along its axis (moved first).

        Raises:
            SourceError: the file's data are damaged or truncated.

        """
        return [self._read(n, a, start, stop) for n, a in zip(names, axes, strict=True)]

    def _read(self, name: str, axis: int, start: int, stop: int) -> FloatArray:
        info = self._datasets[name]
        dataset = self._file[info.path]
        index: list[slice] = [slice(None)] * dataset.ndim
        index[info.axes[axis]] = slice(start, stop)
        try:
            block = np.asarray(dataset[tuple(index)], dtype=np.float64)
        except (OSError, RuntimeError, ValueError) as err:
            raise SourceError(
                f"{self.path}: cannot read {name}: corrupt or truncated {self._kind} "
                f"({first_line(err)})"
            ) from None
        # keep the shown axes (in stored order), then put them in the shown order
        kept = sorted(info.axes)
        block = block.reshape([block.shape[ax] for ax in kept])
        order = [kept.index(ax) for ax in info.axes]
        return np.moveaxis(block.transpose(order), axis, 0)

    def close(self) -> None:
        """Close the file."""
        self._file.close()
