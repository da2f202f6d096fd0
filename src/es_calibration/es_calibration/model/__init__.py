"""The calibration's forward model: the composite law and its candidates, the batched fit."""
