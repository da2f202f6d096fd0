"""The array type aliases of es_calibration (one definition for every module)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

#: Float64 arrays: times, displacements, voltages, temperatures, parameters.
FloatArray = npt.NDArray[np.float64]
#: Boolean masks over samples or actuators.
BoolArray = npt.NDArray[np.bool_]
#: Index arrays (sample or actuator positions).
IndexArray = npt.NDArray[np.intp]
