"""What every reader of a lab recording shows and shares (pure: numpy only).

:class:`Variable` (one named array of a recording), :class:`Timeseries`, the :class:`Source`
protocol every reader implements and two helpers the readers share. Its own module so that
the table of readers (:mod:`.sources`) can name the readers (:mod:`.hdf`, :mod:`.delimited`)
while they import only this: no import cycle.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from es_common.arrays import FloatArray


@dataclass(frozen=True)
class Variable:
    """One array of a recording: its name, shape and dtype (``numeric`` False: unusable)."""

    name: str
    shape: tuple[int, ...]
    dtype: str
    numeric: bool = True


@dataclass(frozen=True)
class Timeseries:
    """A timeseries-like struct: the variables holding its time stamps and its data."""

    time: str
    data: str


class Source(Protocol):
    """A recording opened for import."""

    path: Path

    def variables(self) -> Mapping[str, Variable]:
        """Every array of the recording, numeric or not, by name."""
        ...

    def read(self, names: Sequence[str], axes: Sequence[int], start: int, stop: int
             ) -> list[FloatArray]:
        """Return samples ``start:stop`` of each variable along its time axis (moved first).

        Raises:
            SourceError: a variable is missing or not numeric, or the file is damaged.

        """
        ...

    def close(self) -> None:
        """Release the file."""
        ...


def first_line(err: BaseException) -> str:
    """Return the first line of an exception's message (its class name if it has none)."""
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def numeric_dtype(dtype: np.dtype) -> bool:
    """Return whether arrays of ``dtype`` can become float64 values (bool, int, float)."""
    return dtype.kind in "biuf"
