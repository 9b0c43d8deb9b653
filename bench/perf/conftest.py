"""The benchmarks compute as the `stepzoo` command does: in float64, set before the first
computation (the library itself changes no JAX setting; run.py gives the command's XLA
option)."""
import jax

jax.config.update("jax_enable_x64", True)
