"""Readers of lab recordings behind one small protocol, looked up by file suffix.

Every reader shows the recording as named numeric arrays (:class:`Variable`) and reads a
range of samples of several of them at once along each one's time axis. Formats:

- ``.mat`` v4-v7 (scipy.io, loaded whole: that format has no partial reads), v7.3 (HDF5,
  read in slices). Struct fields are ``struct.field``; size-1 dimensions are dropped, so a
  MATLAB N x 1 column is an (N,) vector in both versions, and v7.3 arrays are shown in
  MATLAB's index order (R x C x N stays R x C x N).
- ``.h5``/``.hdf5``: datasets by path (``group/dataset``), read in slices, shapes as stored.
- ``.csv``/``.tsv``: one header row of column names, one row per sample, read in blocks of
  rows; an empty cell is NaN.
- ``.npz``: NumPy archives (each array loaded whole when first used).

A struct or group with ``Time`` and ``Data`` fields (any case; also Simulink's
"structure with time": ``time`` + ``signals.values``) is a timeseries: its name stands for
its data, with its own time base.
"""

from __future__ import annotations

import zipfile
import zlib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Final

import numpy as np

from es_recordings.labimport.errors import SourceError
from es_recordings.labimport.recording import (
    FloatArray,
    Source,
    Timeseries,
    Variable,
    first_line,
    numeric_dtype,
)

_MAT73_TEXT: Final = b"MATLAB 7.3 MAT-file"


def find_timeseries(variables: Mapping[str, Variable]) -> dict[str, Timeseries]:
    """Return the timeseries-like structs among ``variables`` by struct name.

    A struct (fields joined with ``.``) or group (``/``) is one when it has a ``Time`` field
    and a ``Data`` (or ``signals.values``) field, in any case.
    """
    lower = {name.lower(): name for name in variables}
    found: dict[str, Timeseries] = {}
    for name in variables:
        for sep in "./":
            head, _, leaf = name.rpartition(sep)
            if not head or leaf.lower() != "time":
                continue
            data = lower.get(f"{head}{sep}data".lower()) or lower.get(
                f"{head}{sep}signals{sep}values".lower()
            )
            if data is not None:
                found[head] = Timeseries(name, data)
    return found


def _moved(array: np.ndarray, axis: int, start: int, stop: int) -> FloatArray:
    index: list[slice | int] = [slice(None)] * array.ndim
    index[axis] = slice(start, stop)
    return np.moveaxis(np.asarray(array[tuple(index)], dtype=np.float64), axis, 0)


class ArraySource:
    """A recording loaded whole into named arrays (.mat v4-v7, .npz)."""

    def __init__(self, path: Path, arrays: Mapping[str, np.ndarray]) -> None:
        """Wrap ``arrays`` read from ``path``."""
        self.path = path
        self._arrays = dict(arrays)
        self._variables = {
            name: Variable(name, tuple(a.shape), str(a.dtype), numeric_dtype(a.dtype))
            for name, a in self._arrays.items()
        }

    def variables(self) -> Mapping[str, Variable]:
        """Every array of the recording by name."""
        return self._variables

    def read(self, names: Sequence[str], axes: Sequence[int], start: int, stop: int
             ) -> list[FloatArray]:
        """Return samples ``start:stop`` of each variable along its axis (moved first)."""
        return [_moved(self._arrays[n], a, start, stop) for n, a in zip(names, axes, strict=True)]

    def close(self) -> None:
        """Drop the arrays."""
        self._arrays.clear()


def _flatten(prefix: str, value: object, out: dict[str, np.ndarray]) -> None:
    if isinstance(value, dict):
        for key, item in value.items():
            _flatten(f"{prefix}.{key}" if prefix else str(key), item, out)
        return
    array = np.asarray(value) if not isinstance(value, list) else np.empty(len(value), object)
    out[prefix] = np.squeeze(array) if array.ndim > 1 else array


def _open_mat(path: Path) -> Source:
    try:
        with path.open("rb") as handle:
            head = handle.read(128)
    except OSError as err:
        raise SourceError(f"cannot read {path}: {err.strerror or err}") from None
    if not head:
        raise SourceError(f"{path} is empty")
    if head.startswith(_MAT73_TEXT):
        from es_recordings.labimport.hdf import HdfSource

        return HdfSource(path, matlab=True)
    from scipy.io import loadmat

    try:
        contents = loadmat(path, simplify_cells=True)
    except MemoryError:
        raise SourceError(f"{path}: not enough memory to load this MAT file") from None
    except Exception as err:  # scipy raises assorted errors on damaged files
        raise SourceError(f"{path}: corrupt or truncated MAT file ({first_line(err)})") from None
    arrays: dict[str, np.ndarray] = {}
    for name, value in contents.items():
        if not name.startswith("__"):
            _flatten(name, value, arrays)
    return ArraySource(path, arrays)


def _open_npz(path: Path) -> Source:
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except MemoryError:
        raise SourceError(f"{path}: not enough memory to load this archive") from None
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as err:
        raise SourceError(
            f"{path}: corrupt or truncated .npz archive ({first_line(err)})"
        ) from None
    return ArraySource(path, arrays)


def _open_hdf5(path: Path) -> Source:
    from es_recordings.labimport.hdf import HdfSource

    return HdfSource(path, matlab=False)


def _open_csv(path: Path) -> Source:
    from es_recordings.labimport.delimited import DelimitedSource

    return DelimitedSource(path, ",")


def _open_tsv(path: Path) -> Source:
    from es_recordings.labimport.delimited import DelimitedSource

    return DelimitedSource(path, "\t")


#: The reader of each file suffix.
READERS: Final[Mapping[str, Callable[[Path], Source]]] = {
    ".mat": _open_mat,
    ".h5": _open_hdf5,
    ".hdf5": _open_hdf5,
    ".csv": _open_csv,
    ".tsv": _open_tsv,
    ".npz": _open_npz,
}


def open_source(path: str | Path) -> Source:
    """Open a recording with the reader of its suffix.

    Raises:
        SourceError: the file is missing, its suffix is unknown, or it cannot be read.

    """
    file = Path(path)
    opener = READERS.get(file.suffix.lower())
    if opener is None:
        raise SourceError(
            f"{file}: unknown recording format {file.suffix or '(no suffix)'!r}; "
            f"known: {', '.join(READERS)}"
        )
    if not file.is_file():
        raise SourceError(f"recording not found: {file}")
    return opener(file)
