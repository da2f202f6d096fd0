"""Bounded caches of candidate-independent work of one recording (play passes, low-passes).

The effect search refits many candidates on the same recording: the play operators of the
command at a threshold, a drive signal's low-pass at a time constant, the drive signal
itself depend only on the recording, the rows read and those values, not on the candidate.
:class:`BoundedCache` keeps such results, least recently used first out, under a byte
budget (a 64 x 64 grid's record must stay within its memory target), keyed by exactly
what they depend on. :func:`bypassed` switches every cache off (each lookup misses, nothing
is kept), so a test can show that the caches change no result. The arrays of a kept value
are made read-only: a caller that wrote into one would change every later candidate's
input, so such a write raises instead.
"""

from __future__ import annotations

import dataclasses
from collections import OrderedDict
from collections.abc import Hashable, Iterator
from contextlib import contextmanager
from typing import Any, Final, Generic, TypeVar

import numpy as np

from es_common.arrays import IndexArray

#: Default byte budget of one cache.
DEFAULT_BUDGET_BYTES: Final = 256 * 2**20

V = TypeVar("V")

_bypass = False


@contextmanager
def bypassed() -> Iterator[None]:
    """Switch every :class:`BoundedCache` off inside the block (for tests and benchmarks)."""
    global _bypass  # noqa: PLW0603 - one process-wide switch, restored on exit
    before = _bypass
    _bypass = True
    try:
        yield
    finally:
        _bypass = before


def cache_bypassed() -> bool:
    """Return whether the caches are switched off (see :func:`bypassed`)."""
    return _bypass


def _size(value: Any) -> int:
    """Return the bytes of the arrays in ``value`` (an array, tuples or dataclasses of them)."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, tuple):
        return sum(_size(v) for v in value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return sum(_size(getattr(value, f.name)) for f in dataclasses.fields(value))
    return 0


def _freeze(value: Any) -> None:
    """Make the arrays in ``value`` (an array, tuples or dataclasses of them) read-only."""
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif isinstance(value, tuple):
        for item in value:
            _freeze(item)
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for field in dataclasses.fields(value):
            _freeze(getattr(value, field.name))


def rows_key(rows: IndexArray) -> bytes:
    """Return a key for a row index array: its contents (equal rows, equal key; exact)."""
    return np.ascontiguousarray(rows, np.intp).tobytes()


class BoundedCache(Generic[V]):
    """A least-recently-used mapping whose arrays stay within ``budget_bytes``."""

    def __init__(self, budget_bytes: int = DEFAULT_BUDGET_BYTES, max_entries: int = 1024):
        """Keep at most ``budget_bytes`` of arrays in at most ``max_entries`` entries."""
        self.budget_bytes = int(budget_bytes)
        self.max_entries = int(max_entries)
        self._entries: OrderedDict[Hashable, tuple[V, int]] = OrderedDict()
        self._bytes = 0
        self.hits = 0
        self.misses = 0

    @property
    def nbytes(self) -> int:
        """Return the bytes held."""
        return self._bytes

    def get(self, key: Hashable) -> V | None:
        """Return the value under ``key`` (now the most recently used), or None."""
        if _bypass or key not in self._entries:
            self.misses += 1
            return None
        self._entries.move_to_end(key)
        self.hits += 1
        return self._entries[key][0]

    def put(self, key: Hashable, value: V) -> V:
        """Keep ``value`` under ``key`` (unless bypassed or larger than the budget); return it.

        The arrays of a kept value become read-only (see the module's docstring).
        """
        if _bypass:
            return value
        size = _size(value)
        if key in self._entries:
            self._bytes -= self._entries.pop(key)[1]
        if size > self.budget_bytes:
            return value
        while self._entries and (
            self._bytes + size > self.budget_bytes or len(self._entries) >= self.max_entries
        ):
            self._bytes -= self._entries.popitem(last=False)[1][1]
        _freeze(value)
        self._entries[key] = (value, size)
        self._bytes += size
        return value
