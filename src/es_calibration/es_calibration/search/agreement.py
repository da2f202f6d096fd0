"""When two fits of the same effect disagree: the rule the stand-in checks share.

A parameter fitted twice (on the two halves of the record, :mod:`.halves`; without and with
a free offset per actuator, :mod:`.offsets`) moves when the two values differ by more than
``AGREE_SIGMAS`` combined 1-sigma *and* by more than ``AGREE_RELATIVE`` of the larger
magnitude: a real effect keeps its value, one fitted to something else changes with it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np

#: Combined 1-sigma uncertainties two fits' values may differ by.
AGREE_SIGMAS: Final = 4.0
#: Share of the larger magnitude two fits' values may differ by.
AGREE_RELATIVE: Final = 0.5

#: A moved parameter: (name, first value, second value, combined 1-sigma).
Moved = tuple[str, float, float, float]


class NotANumberError(ValueError):
    """A parameter that is not a number in one of the two fits."""


def disagreement(
    values: Sequence[dict[str, float]], sigmas: Sequence[dict[str, float]]
) -> Moved | None:
    """Return the first parameter whose two fits disagree (see the module), or None.

    ``values`` and ``sigmas`` hold the two fits' reported parameters and 1-sigma; a
    parameter without an uncertainty in both is not compared.

    Raises:
        NotANumberError: a compared parameter is not finite in one of the fits.

    """
    first, second = values
    for key in sigmas[0]:
        if key not in first or key not in sigmas[1]:
            continue
        a, b = first[key], second[key]
        if not (np.isfinite(a) and np.isfinite(b)):
            raise NotANumberError(key)
        combined = float(np.hypot(sigmas[0][key], sigmas[1][key]))
        gap = abs(a - b)
        if gap > AGREE_SIGMAS * combined and gap > AGREE_RELATIVE * max(abs(a), abs(b)):
            return key, a, b, combined
    return None
