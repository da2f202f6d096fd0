"""Recordings of the independent test stand (testing/standgen) as the calibration's input."""

from __future__ import annotations

from typing import TYPE_CHECKING

from es_calibration.data.align import MeasuredData

if TYPE_CHECKING:  # only for annotations: the data helpers take a Recording from standgen
    from standgen import Recording


def measured(r: Recording) -> MeasuredData:
    """Return the topics of the stand recording ``r`` as the calibration's measured data."""
    return MeasuredData(
        r.command_times,
        r.command,
        r.displacement_times,
        r.displacement,
        r.temperature_times,
        r.temperature,
    )
