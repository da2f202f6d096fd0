"""Calibration tool tests (a package so that their data helpers import as calibration.*)."""
