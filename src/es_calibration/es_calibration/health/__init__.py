"""Recording health: faults of the recording found and named before the physics is fitted."""
