"""The exception classes of es_msgs_py, in one place (pure: no imports at all).

Every class subclasses the builtin it refines (``ValueError``), so a generic handler still
catches them, while a caller that wants "a bag problem" or "a layout problem" catches just that.

- :class:`LayoutError`: a ``Float64MultiArray`` (message or bag payload) breaks the contract's
  layout, size or length (raised by :mod:`es_msgs_py.arrays` and the bag codec).
- :class:`BagError` and its subclasses: a bag cannot be read or written
  (:mod:`es_msgs_py.bag`; also exported there as :mod:`es_msgs_py.bag.errors`). Each message
  is one readable line.

The node runtime's parameter errors are :mod:`es_node_runtime.errors`.
"""

from __future__ import annotations

__all__ = [
    "BagError",
    "BagExistsError",
    "BagLayoutError",
    "BagNotFoundError",
    "BagWriteError",
    "CorruptBagError",
    "LayoutError",
    "MissingTopicError",
    "NotABagError",
    "UnknownMessageTypeError",
    "UnsupportedBagError",
]


class LayoutError(ValueError):
    """A message's layout, size or length does not match what the receiver expects."""


class BagError(ValueError):
    """A bag cannot be read or written; the message is one readable line."""


class BagNotFoundError(BagError):
    """The bag path does not exist."""


class NotABagError(BagError):
    """The path exists but is no rosbag2 bag (a file, no storage, foreign or empty files)."""


class CorruptBagError(BagError):
    """The bag's storage or metadata is damaged, or a cleanly closed bag was truncated."""


class UnsupportedBagError(BagError):
    """The bag uses a feature this reader does not read (compression, CDR encapsulation)."""


class MissingTopicError(BagError):
    """A requested topic is not in the bag."""


class UnknownMessageTypeError(BagError):
    """A message type is neither a standard ROS 2 Jazzy type nor defined in the bag."""


class BagLayoutError(BagError, LayoutError):
    """An array in (or for) a bag breaks the contract's layout, or changes shape in a topic."""


class BagWriteError(BagError):
    """A bag cannot be created or a write is refused (closed bag, wrong type, bad storage)."""


class BagExistsError(BagWriteError):
    """The path of a new bag exists already; a bag is never overwritten."""
