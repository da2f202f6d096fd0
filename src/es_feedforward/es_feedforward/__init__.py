"""Electrostrictive actuator models, temperature-compensated feedforward and calibration."""
