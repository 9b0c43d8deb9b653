"""The implicit methods whose driver throughput `make bench` compares with rk4's, and the
batches it compares them at: bench_driver.py runs them, run.py forms the ratios. Nothing here
imports JAX: run.py reads it in the process that only starts the benchmarks."""
IMPLICIT = ("trapezoidal", "backward_euler", "radau_iia5", "bdf2", "bdf3", "bdf4", "bdf5")
IMPLICIT_BATCHES = (1, 10_000)
