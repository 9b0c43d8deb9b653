"""What the benchmarks share: the bicycle problem every contender solves, the implicit methods
compared, and the RK4 baselines (NumPy, Numba, plain JAX, diffrax) doing the same work."""
