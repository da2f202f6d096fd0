"""The array type aliases of every es_dm package (one definition, imported everywhere).

Static types only: each alias is a ``numpy.typing.NDArray`` of one dtype, checked by mypy and
free at run time. Shapes are not part of the type; a function's docstring states them.
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
import numpy.typing as npt

__all__ = ["BoolArray", "FloatArray", "IndexArray", "IntArray"]

#: Float64 arrays: times, displacements, voltages, temperatures, parameters.
FloatArray: TypeAlias = npt.NDArray[np.float64]
#: Boolean masks over samples, sensors or actuators.
BoolArray: TypeAlias = npt.NDArray[np.bool_]
#: Index arrays (sample, sensor or actuator positions), numpy's own index type.
IndexArray: TypeAlias = npt.NDArray[np.intp]
#: 64-bit integer arrays: counts and integer data that are not positions.
IntArray: TypeAlias = npt.NDArray[np.int64]
