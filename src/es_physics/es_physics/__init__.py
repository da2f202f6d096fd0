"""Electrostrictive actuator physics shared by plant, feedforward and calibration.

No ROS here: parameters and their temperature laws (:mod:`es_physics.params`), the
displacement models and their inverses (:mod:`es_physics.laws`).
"""

__version__ = "0.1.0"
