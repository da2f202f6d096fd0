"""What a calibration writes: calibration.json, the parameters YAML, the report and figures."""
