"""Measured-data bags read whole, through the streaming path the calibration tool uses.

The tool never holds a whole grid topic (es_calibration.data.bagstream.BagRecording); tests
that look at every sample build the in-memory :class:`MeasuredData` from the same two passes,
so they read bags exactly as ``calibrate`` does (same checks, same one-line errors, same
stamp order).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from es_calibration.data.align import MeasuredData
from es_calibration.data.bagstream import BagRecording
from es_calibration.data.recording import COMMAND_ROLE, DISPLACEMENT_ROLE
from es_calibration.search.state import screen_block


def read_measured_bags(paths: Sequence[str | Path]) -> MeasuredData:
    """Return every sample of the bags of one mirror (several concatenated in time order)."""
    recording = BagRecording(paths)
    rows, cols = recording.grid
    first = recording.block(*screen_block(recording.grid))  # every stamp, the temperature topic
    grids = {
        COMMAND_ROLE: np.full((first.command_times.size, rows * cols), np.nan),
        DISPLACEMENT_ROLE: np.full((first.displacement_times.size, rows * cols), np.nan),
    }
    for role, index, values in recording.batches():
        grids[role][index] = values
    temperature_times, temperature = recording.temperature()
    return MeasuredData(
        command_times=first.command_times,
        command=grids[COMMAND_ROLE].reshape(-1, rows, cols),
        displacement_times=first.displacement_times,
        displacement=grids[DISPLACEMENT_ROLE].reshape(-1, rows, cols),
        temperature_times=temperature_times,
        temperature=temperature.reshape(-1, rows, cols),
        temperature_source=first.temperature_source,
    )
