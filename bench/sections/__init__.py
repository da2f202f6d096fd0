"""Benchmark sections: one module each with ``run(context: benchlib.Context)``."""
