"""Deformable-mirror plant simulator: UV heating, thermal network, actuator grid, sensors."""
