"""Performance benchmarks (pytest-benchmark): the driver against NumPy, Numba, diffrax and
SciPy baselines on the same problem, the sweep, the planner and the connection OCP.
`python -m bench.perf.run` runs them and writes bench/results/."""
