"""Clocks and prices: where a chunk's time goes, JAX's compile seconds, repeated
timings summarised as pytest-benchmark does, and each method's calibrated cost per step."""
