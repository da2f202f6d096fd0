"""The errors of bag I/O: :class:`BagError` (a ``ValueError``) and its finer subclasses.

Defined once in :mod:`es_msgs_py.errors` (dependency-free, with the package's other
exceptions) and re-exported here, so bag code and its callers name them from the bag package.
"""

from __future__ import annotations

from es_msgs_py.errors import (
    BagError,
    BagExistsError,
    BagLayoutError,
    BagNotFoundError,
    BagWriteError,
    CorruptBagError,
    MissingTopicError,
    NotABagError,
    UnknownMessageTypeError,
    UnsupportedBagError,
)

__all__ = [
    "BagError",
    "BagExistsError",
    "BagLayoutError",
    "BagNotFoundError",
    "BagWriteError",
    "CorruptBagError",
    "MissingTopicError",
    "NotABagError",
    "UnknownMessageTypeError",
    "UnsupportedBagError",
]
