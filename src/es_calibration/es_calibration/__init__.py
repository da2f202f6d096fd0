"""Calibration of the actuator model from measured data (pure numpy/scipy, no rclpy).

Pipeline: :mod:`.bagio` (read bags) -> :mod:`.align` (time base, train/held-out blocks) ->
:mod:`.search` (batched law fit :mod:`.fit` of the composite :mod:`.model`, greedy effect
search) -> :mod:`.residual` (held-out residual structure) -> :mod:`.schema` (calibration.json,
feedforward parameters YAML) and :mod:`.report` (Markdown and figures). The CLI is
:mod:`es_calibration.calibrate`; :func:`.pipeline.calibrate` runs everything in memory.
"""
