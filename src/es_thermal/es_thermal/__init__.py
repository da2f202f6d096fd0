"""Per-actuator temperature estimation from noisy, sparse, lagging sensors."""
