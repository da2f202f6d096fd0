"""Discovery of effects no registry entry describes: a generic term library, sparse selection.

:func:`discover` (step.py) runs after the registry search on its held-out residual, and
:func:`refit_with_terms` (exact.py) refits the model with the terms written; library.py builds
the terms, regression.py selects them, limit.py searches a slew-rate limit behind the drive,
exact.py takes terms out of the data as the feedforward undoes them, standins.py judges the
registry's effects against the terms, terms.py holds the result.
"""

from es_calibration.discovery.exact import refit_with_terms
from es_calibration.discovery.step import discover
from es_calibration.discovery.terms import DiscoveredTerm, Discovery

__all__ = ["DiscoveredTerm", "Discovery", "discover", "refit_with_terms"]
