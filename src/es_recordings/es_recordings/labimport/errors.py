"""Errors of the lab-recording importer; each message is one readable line."""

from __future__ import annotations


class LabImportError(ValueError):
    """A lab recording cannot be imported (base class of every importer error)."""


class MapError(LabImportError):
    """The map file is unreadable or invalid (bad YAML, unknown key, unit not in the list)."""


class SourceError(LabImportError):
    """The recording is unreadable or its data do not fit the map.

    For example a missing variable, lengths that differ from the time base, a non-increasing
    time, a grid size that does not match, a corrupt or truncated file.
    """
