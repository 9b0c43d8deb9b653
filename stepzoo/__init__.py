"""stepzoo: integrator stability benchmarking, and the sampling tree planner fed the tuned step.

Subpackages, lowest layer first: `stepzoo.dynamics` (models), `stepzoo.integrators` (the zoo),
`stepzoo.bench` and `stepzoo.search`, `stepzoo.reports`. The modules beside this file
(`errors`, `output`, `validate`) are the shared plumbing under all of them. Importing stepzoo
changes no JAX setting: the library works in the caller's precision and on its platform."""
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("stepzoo")
except PackageNotFoundError:          # a source tree that was never installed
    __version__ = "0+unknown"
