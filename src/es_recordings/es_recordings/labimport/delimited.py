"""CSV and TSV recordings: a header row of column names, then one row per sample.

Opening makes one pass over the file that counts the rows and checks that each has as many
fields as the header (a cut or damaged file fails here, naming the line). Reads then parse
blocks of rows with numpy; an empty cell is NaN. Lines before the header that start with
``#`` are comments.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import islice
from pathlib import Path
from typing import IO

import numpy as np

from es_recordings.labimport.errors import SourceError
from es_recordings.labimport.recording import FloatArray, Variable


class DelimitedSource:
    """A CSV (comma-separated) or TSV (tab-separated) file opened for import."""

    def __init__(self, path: Path, delimiter: str) -> None:
        """Open ``path``, read its header and count and check its rows.

        Raises:
            SourceError: the file cannot be read, has no header, repeats a column name, or a
                row has the wrong number of fields.

        """
        self.path = path
        self._delimiter = delimiter
        try:
            self._handle: IO[str] = path.open(newline="")
        except OSError as err:
            raise SourceError(f"cannot read {path}: {err.strerror or err}") from None
        try:
            self._header_lines, names = self._header()
            self._rows = self._count(len(names))
        except UnicodeDecodeError:
            self._handle.close()
            raise SourceError(f"{path}: not a text file (corrupt CSV?)") from None
        except SourceError:
            self._handle.close()
            raise
        self._columns = {name: i for i, name in enumerate(names)}
        self._variables = {n: Variable(n, (self._rows,), "float64") for n in names}
        self._row = -1  # rows consumed since the header; -1: at the file's start

    def _header(self) -> tuple[int, list[str]]:
        for number, line in enumerate(self._handle, 1):
            if line.startswith("#"):
                continue
            names = [n.strip().strip('"').strip() for n in line.rstrip("\r\n").split(
                self._delimiter)]
            if not any(names) or not all(names):
                raise SourceError(f"{self.path}: line {number}: empty column name in header")
            repeated = sorted({n for n in names if names.count(n) > 1})
            if repeated:
                raise SourceError(f"{self.path}: column(s) {', '.join(repeated)} appear twice")
            return number, names
        raise SourceError(f"{self.path}: no header row (the file is empty)")

    def _count(self, columns: int) -> int:
        rows = blank = 0
        for number, line in enumerate(self._handle, self._header_lines + 1):
            if not line.strip():
                blank += 1
                continue
            if blank:
                raise SourceError(f"{self.path}: line {number - 1} is empty")
            fields = line.count(self._delimiter) + 1
            if fields != columns:
                raise SourceError(
                    f"{self.path}: line {number} has {fields} fields, the header {columns} "
                    "(truncated or corrupt file?)"
                )
            rows += 1
        return rows

    def variables(self) -> Mapping[str, Variable]:
        """Every column by name (each an (N,) float64 vector)."""
        return self._variables

    def _seek(self, row: int) -> None:
        if self._row != row:
            self._handle.seek(0)
            for _ in islice(self._handle, self._header_lines):
                pass
            self._row = 0
            for _ in islice(self._handle, row):
                pass
            self._row = row

    def read(self, names: Sequence[str], axes: Sequence[int], start: int, stop: int
             ) -> list[FloatArray]:
        """Return rows ``start:stop`` of the named columns (``axes`` are all 0 here).

        Raises:
            SourceError: a cell is not a number.

        """
        self._seek(start)
        lines = list(islice(self._handle, stop - start))
        self._row = start + len(lines)
        usecols = [self._columns[n] for n in names]
        try:
            block = np.loadtxt(lines, delimiter=self._delimiter, usecols=usecols, ndmin=2,
                               dtype=np.float64, comments=None)
        except ValueError:
            block = self._parse_slowly(lines, usecols, start)
        return [block[:, i] for i in range(len(usecols))]

    def _parse_slowly(self, lines: list[str], usecols: list[int], start: int) -> FloatArray:
        """Parse rows one by one: empty cells become NaN, anything else bad is named."""
        names = list(self._variables)
        block = np.empty((len(lines), len(usecols)))
        for i, line in enumerate(lines):
            fields = line.rstrip("\r\n").split(self._delimiter)
            for j, col in enumerate(usecols):
                cell = fields[col].strip().strip('"')
                try:
                    block[i, j] = float(cell) if cell else np.nan
                except ValueError:
                    number = self._header_lines + start + i + 1
                    raise SourceError(
                        f"{self.path}: line {number}, column {names[col]}: {cell[:40]!r} "
                        "is not a number"
                    ) from None
        return block

    def close(self) -> None:
        """Close the file."""
        self._handle.close()
