"""The mirror's lumped thermal parameters per actuator cell, and their default values (pure).

One definition for the simulator (:class:`es_sim_plant.thermal.ThermalParams`) and the
estimator (:class:`es_thermal.network.NetworkParams`): both subclass :class:`CellThermalParams`
and add their own checks, so their names and defaults cannot drift apart. The network they
describe (per cell a face-sheet node and an actuator node, the base plate below) is in
es_sim_plant.thermal's docstring.

Default values (a 5 mm pitch grid behind a 4 mm glass face sheet, PMN-PT actuator columns):

- face sheet cell, ULE/fused silica (k = 1.3 W/m/K, rho c = 1.63 MJ/m^3/K), 5 x 5 x 4 mm:
  C_f = 0.163 J/K; lateral conductance k t = 1.3 * 0.004 = 5.2 mW/K;
- actuator column 3 x 3 x 8 mm (PMN-PT layers, glue, pedestal; k ~ 1.5 W/m/K,
  rho c ~ 2.6 MJ/m^3/K): C_a = 0.187 J/K, column conductance k A / h = 1.7 mW/K, split into
  face->actuator and actuator->base halves of twice that (3.4 mW/K each, in series);
- lateral conduction in the actuator layer (filler, flexures): 0.2 mW/K.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CellThermalParams"]


@dataclass(frozen=True)
class CellThermalParams:
    """Uniform per-cell parameters of the thermal network (SI units, see the module docstring).

    Attributes:
        face_capacitance: C_f, heat capacity of one face-sheet cell [J/K].
        actuator_capacitance: C_a, heat capacity of one actuator column [J/K].
        face_to_actuator: G_fa, face-sheet cell to actuator conductance [W/K].
        actuator_to_base: G_ab, actuator to base-plate conductance [W/K].
        face_lateral: G_ff, face-sheet conductance between neighbouring cells [W/K].
        actuator_lateral: G_aa, actuator-layer conductance between neighbours [W/K].

    """

    face_capacitance: float = 0.163
    actuator_capacitance: float = 0.187
    face_to_actuator: float = 3.4e-3
    actuator_to_base: float = 3.4e-3
    face_lateral: float = 5.2e-3
    actuator_lateral: float = 0.2e-3
