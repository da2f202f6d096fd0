"""Discovery of effects no registry entry describes: a generic term library, sparse selection.

:func:`discover` (step.py) runs after the registry search on its held-out residual;
library.py builds the terms, regression.py selects them, terms.py holds the result.
"""

from es_calibration.discovery.step import discover
from es_calibration.discovery.terms import DiscoveredTerm, Discovery

__all__ = ["DiscoveredTerm", "Discovery", "discover"]
