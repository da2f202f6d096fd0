"""The array type alias of the test stand (its own: standgen shares no code with the product)."""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
import numpy.typing as npt

#: Float64 arrays: times, voltages, displacements, temperatures.
FloatArray: TypeAlias = npt.NDArray[np.float64]
