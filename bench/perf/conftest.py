"""The benchmarks compute as the `stepzoo` command does: in float64, set before the first
computation (the library itself changes no JAX setting; run.py gives the command's XLA
option); and they time plans in the process that makes them: a `stepzoo serve` named by
STEPZOO_SERVER would take the `stepzoo plan` calls the benchmarks time in-process."""
import os

import jax

jax.config.update("jax_enable_x64", True)
os.environ.pop("STEPZOO_SERVER", None)
