"""standgen: an independent test-stand generator of measured-data bags (see README.md).

A second implementation of ../shared/docs/physics.md that shares no code with es_sim_plant,
es_feedforward or es_thermal: the yardstick of the calibration's identification sweep.
"""

from standgen.bagfile import StandBagError, write_bag
from standgen.effects import Effects, EffectSetError, draw_effects
from standgen.physics import Law
from standgen.ranges import FAMILIES, RANGES, STAND_RANGES
from standgen.stand import Recording, StandConfig, StandConfigError, simulate

__all__ = [
    "FAMILIES",
    "RANGES",
    "STAND_RANGES",
    "EffectSetError",
    "Effects",
    "Law",
    "Recording",
    "StandBagError",
    "StandConfig",
    "StandConfigError",
    "draw_effects",
    "simulate",
    "write_bag",
]
