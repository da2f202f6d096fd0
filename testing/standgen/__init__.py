"""standgen: an independent test-stand generator of measured-data bags (see README.md).

A second implementation of ../shared/docs/physics.md that shares no code with es_sim_plant,
es_feedforward or es_thermal: the yardstick of the calibration's identification sweep.
"""

from standgen.bagfile import StandBagError, write_bag
from standgen.effects import Effects, EffectSetError, draw_effects
from standgen.faults import FaultError, Faults, draw_fault
from standgen.physics import Law
from standgen.ranges import FAMILIES, FAULT_FAMILIES, RANGES, STAND_RANGES, UNLISTED_FAMILIES
from standgen.stand import Recording, StandConfig, StandConfigError, simulate
from standgen.unlisted import Unlisted, UnlistedError, draw_unlisted

__all__ = [
    "FAMILIES",
    "FAULT_FAMILIES",
    "RANGES",
    "STAND_RANGES",
    "UNLISTED_FAMILIES",
    "EffectSetError",
    "Effects",
    "FaultError",
    "Faults",
    "Law",
    "Recording",
    "StandBagError",
    "StandConfig",
    "StandConfigError",
    "Unlisted",
    "UnlistedError",
    "draw_effects",
    "draw_fault",
    "draw_unlisted",
    "simulate",
    "write_bag",
]
