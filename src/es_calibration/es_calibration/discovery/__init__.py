"""Discovery of effects no registry entry describes: a generic term library, sparse selection.

:func:`discover` (step.py) runs after the registry search on its held-out residual, and
:func:`refit_with_terms` refits the model with the terms written; library.py builds the terms,
regression.py selects them, terms.py holds the result.
"""

from es_calibration.discovery.step import discover, refit_with_terms
from es_calibration.discovery.terms import DiscoveredTerm, Discovery

__all__ = ["DiscoveredTerm", "Discovery", "discover", "refit_with_terms"]
