"""Calibration of the actuator model from measured data (pure numpy/scipy, no rclpy).

Grouped by concern, in the order of one run (:func:`.pipeline.calibrate` runs everything in
memory; the CLI is :mod:`.calibrate`):

- :mod:`.data`: where the measured data come from (:mod:`.data.recording`, bags streamed by
  :mod:`.data.bagstream` or read whole by :mod:`.data.bags`) and how they are aligned
  (:mod:`.data.align`: time base, training and held-out blocks; gaps, edges, repeated stamps,
  the search span);
- :mod:`.model`: the composite forward model and its candidate effects
  (:mod:`.model.composite`), the batched law fit (:mod:`.model.fit`), the drive history;
- :mod:`.search`: model states (:mod:`.search.state`), each candidate's fit
  (:mod:`.search.scans`, :mod:`.search.playfit`), the selection, per-actuator values, the
  held-out residual's structure and what stays unexplained;
- :mod:`.grid`: the grid-wide refit in tiles (serial or on Dask) with the tiles on disk;
- :mod:`.output`: calibration.json and the feedforward parameters YAML
  (:mod:`.output.schema`), the Markdown report and figures (:mod:`.output.report`).

Array type aliases come from :mod:`es_common.arrays`; exception classes are in :mod:`.errors`.
"""
